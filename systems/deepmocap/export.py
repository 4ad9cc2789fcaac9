"""DeepMoCap's exporters: labelled 3D markers as C3D (ezc3d) or TRC files, solved poses as BVH.

Both marker formats carry the labels (DeepMoCap's reflector names), the frame rate and the unit (millimetres, the
convention of both). C3D keeps the Z-up world of mocapflow (POINT:X_SCREEN/Y_SCREEN) and stores floats
(formats/c3d.py). Its residual is the mean distance of the fused views from the point (mm) for markers3d, 0 for a
smoothed stage (the C3D convention for filtered or interpolated data: no measurement residual) and -1 for a missing
point; the camera bits name the fused views (the first seven) for markers3d, none once filtered.
TRC is Y up by default (OpenSim's convention: the world rotated about x, x stays, y = z, z = -y, so handedness is
kept) or Z up on request (formats/trc.py).

BVH (formats/bvh.py) follows the convention of animation tools: Y up, the subject facing +Z, centimetres: of the body
fitted to the reflectors (the default poses), Anny's whole rig at the take's phenotype, whose forward kinematics give
the fitted bones' heads; of the template's poses, its 20 joints, frames the solver left unsolved holding the
nearest solved pose.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import xarray as xr

from mocapflow.formats import bvh, c3d, trc
from mocapflow.pipeline.errors import InputError
from mocapflow.pipeline.export import UNIT_SCALE, target, write_atomically
from mocapflow.pipeline.registry import ExportJob, Exporter
from mocapflow.tasks.shared.body import JOINT_NAMES, PARENTS
from mocapflow.tasks.shared.kinematics import Y_UP_TO_Z_UP
from mocapflow.tasks.shared.mesh_body import PHENOTYPE_NAMES, Phenotype, mesh_body


def _arrays(markers: xr.Dataset) -> tuple[np.ndarray, list[str], float, np.ndarray]:
    """xyz (frame, marker, 3) mm in the Z-up world, labels, rate, residual (frame, marker) mm: the mean distance of
    the fused views from the point where the stage keeps one (markers3d), 0 for a point that filtering produced
    (the C3D convention for processed data), -1 where the point is missing."""
    up = str(markers.attrs.get("up_axis", "Z"))
    if up.upper() != "Z":
        raise InputError(f"markers with up_axis {up!r} cannot be exported: the export rotates the Z-up world of "
                         "mocapflow; recompute the markers (their up_axis must be 'Z')")
    xyz = markers["position"].transpose("frame", "reflector", "xyz").values.astype(np.float64) * UNIT_SCALE
    names = [str(n) for n in markers["reflector"].values]
    fps = float(markers.attrs["fps"])
    residual = np.zeros(xyz.shape[:2])
    if "residual" in markers:
        per_view = markers["residual"].transpose("frame", "reflector", "view").values.astype(np.float64)
        seen = np.isfinite(per_view).any(axis=-1)
        residual[seen] = np.nanmean(per_view[seen], axis=-1) * UNIT_SCALE
    residual = np.where(np.isfinite(xyz).all(axis=-1), residual, -1.0)
    return xyz, names, fps, residual


def _camera_masks(markers: xr.Dataset, shape: tuple[int, int]) -> np.ndarray:
    """C3D camera bits (frame, marker): bit v set where view v (the first 7 views) was fused; 0 for filtered data."""
    mask = np.zeros(shape, dtype=np.int64)
    if "residual" in markers:
        seen = np.isfinite(markers["residual"].transpose("frame", "reflector", "view").values)[..., :7]
        mask = (seen * (1 << np.arange(seen.shape[-1]))).sum(axis=-1)
    return mask


def write_c3d(markers: xr.Dataset, path: Path) -> None:
    xyz, names, fps, residual = _arrays(markers)
    scale = c3d.c3d_scale(xyz, residual)
    word4 = np.where(residual < 0, -1, (_camera_masks(markers, residual.shape) << 8)
                     | np.clip(np.rint(residual / abs(scale)), 0, 255).astype(np.int64))
    write_atomically(path, lambda p: c3d.write_points(p, xyz, names, fps, scale, word4), ".c3d")


# mocapflow world (Z up) -> TRC Y up: x stays, y = z, z = -y (a rotation about x, so handedness is kept)
TRC_Y_UP = Y_UP_TO_Z_UP.T  # the inverse rotation
TRC_UP = ("y", "z")


def write_trc(markers: xr.Dataset, path: Path, up: str = "y") -> None:
    """TRC in millimetres, Y up by default (OpenSim's convention; ``up="z"`` keeps the Z-up world). The up axis is
    written in an ``UpAxis`` column after the eight standard header fields."""
    if up not in TRC_UP:
        raise InputError(f"TRC up axis {up!r} is not one of {list(TRC_UP)}; pass --up y (OpenSim) or --up z")
    xyz, names, fps, _ = _arrays(markers)
    if up == "y":
        xyz = xyz @ TRC_Y_UP.T
    text = trc.trc_text(xyz, names, fps, markers["frame"].values, up, path.name)
    write_atomically(path, lambda p: p.write_text(text), ".trc")


def _filled(poses: xr.Dataset) -> tuple[np.ndarray, np.ndarray]:
    """Local rotations (frame, joint, 4) and root positions (frame, 3), unsolved frames held from the nearest solved."""
    quat = poses["rotation"].transpose("frame", "joint", "quat").values.astype(np.float64)
    root = poses["position"].transpose("frame", "joint", "xyz").values[:, 0].astype(np.float64)
    solved = np.isfinite(quat).all(axis=(1, 2)) & np.isfinite(root).all(axis=1)
    if not solved.any():
        raise InputError("the poses hold no solved frame; nothing to write as BVH (check the markers and skeleton stages)")
    nearest = np.flatnonzero(solved)[np.abs(np.arange(len(solved))[:, None] - np.flatnonzero(solved)).argmin(axis=1)]
    return quat[nearest], root[nearest]


def poses_bvh(poses: xr.Dataset) -> str:
    """BVH text (Y up, centimetres) of solved poses on their skeleton."""
    names = [str(n) for n in poses["joint"].values]
    parents = _parents(poses)
    quat, root = _filled(poses)
    return bvh.bvh_text(names, parents, poses["offset"].transpose("joint", "xyz").values.astype(np.float64), quat, root,
                    float(poses.attrs["fps"]))


def _parents(poses: xr.Dataset) -> np.ndarray:
    names = [str(n) for n in poses["joint"].values]
    if names != list(JOINT_NAMES):
        raise InputError(f"poses joints {names} are not the template's {list(JOINT_NAMES)}; BVH export needs the template")
    return PARENTS


def body_bvh(body: xr.Dataset) -> str:
    """BVH text of the body fitted to the reflectors: Anny's whole rig at the take's phenotype."""
    phenotype = Phenotype(**dict(zip(PHENOTYPE_NAMES, map(float, body["shape"].sel(phenotype=list(PHENOTYPE_NAMES))))))
    return bvh.anny_rig_bvh(mesh_body(phenotype), body["bone_rotation"].values, body["root"].values,
                            float(body.attrs["fps"]))


def write_bvh(poses: xr.Dataset, path: Path) -> None:
    """The poses as BVH: Anny's rig for a body fitted to the reflectors, the template's 20 joints for its poses."""
    text = body_bvh(poses) if "bone_rotation" in poses else poses_bvh(poses)
    write_atomically(path, lambda p: p.write_text(text), ".bvh")


def _export(write, suffix: str):
    def run(job: ExportJob) -> list[Path]:
        path = target(job.out_dir, f"{job.sequence}.{suffix}")
        write(job, path)
        return [path]
    return run


EXPORTERS = (
    Exporter("c3d", ("smoothed_markers", "markers3d"), _export(lambda job, path: write_c3d(job.data, path), "c3d")),
    Exporter("trc", ("smoothed_markers", "markers3d"),
             _export(lambda job, path: write_trc(job.data, path, job.up or "y"), "trc"), options=("up",)),
    Exporter("bvh", ("body_poses", "poses"), _export(lambda job, path: write_bvh(job.data, path), "bvh")),
)

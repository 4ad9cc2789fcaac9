"""`mocapflow export`: labelled 3D markers as C3D (ezc3d) or TRC files, solved poses as BVH.

Both carry the labels (DeepMoCap's reflector names), the frame rate, the unit (millimetres, the
convention of both formats) and the up axis (Z, the world frame of mocapflow): C3D in POINT:UNITS
and POINT:X_SCREEN/Y_SCREEN, TRC in its Units column and an UpAxis column after the standard ones.
Missing samples are NaN with residual -1 in C3D and empty fields in TRC.

BVH follows the convention of animation tools: Y up, the subject facing +Z, centimetres, the template's 20 joints (each
leaf closed by an End Site continuing its bone), root channels ``X/Y/Zposition Z/X/Yrotation`` and
``Z/X/Yrotation`` elsewhere. Frames the solver left unsolved hold the nearest solved pose.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import xarray as xr

from scipy.spatial.transform import Rotation

from mocapflow.pipeline.errors import InputError, PlanError, StorageError
from mocapflow.pipeline.evaluate import stage_writing
from mocapflow.pipeline.plan import build_plan, select
from mocapflow.pipeline.storage import Store
from mocapflow.tasks.shared.body import JOINT_NAMES, PARENTS
from mocapflow.tasks.studio.bvh import parse_bvh

UNIT_SCALE = 1000.0  # metres -> millimetres
BVH_SCALE = 100.0  # metres -> centimetres
# mocapflow world (x right, y forward, z up) -> BVH (Y up, facing +Z, the subject's left +X)
Z_UP_TO_Y_UP = np.array([[-1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, 1.0, 0.0]])


def _arrays(markers: xr.Dataset) -> tuple[np.ndarray, list[str], float, np.ndarray]:
    xyz = markers["position"].transpose("frame", "reflector", "xyz").values.astype(np.float64) * UNIT_SCALE
    names = [str(n) for n in markers["reflector"].values]
    fps = float(markers.attrs["fps"])
    if "residual" in markers:
        residual = np.nanmean(markers["residual"].transpose("frame", "reflector", "view").values, axis=-1) * UNIT_SCALE
    else:
        residual = np.zeros(xyz.shape[:2])
    residual = np.where(np.isnan(xyz[..., 0]), -1.0, np.nan_to_num(residual, nan=0.0))
    return xyz, names, fps, residual


def write_c3d(markers: xr.Dataset, path: Path) -> None:
    import ezc3d

    xyz, names, fps, residual = _arrays(markers)
    c3d = ezc3d.c3d()
    c3d["parameters"]["POINT"]["RATE"]["value"] = [fps]
    c3d["parameters"]["POINT"]["LABELS"]["value"] = names
    c3d["parameters"]["POINT"]["UNITS"]["value"] = ["mm"]
    c3d.add_parameter("POINT", "X_SCREEN", "+X")
    c3d.add_parameter("POINT", "Y_SCREEN", "+Z")  # Z up
    points = np.ones((4, len(names), xyz.shape[0]))
    points[:3] = xyz.transpose(2, 1, 0)  # (xyz, marker, frame)
    c3d["data"]["points"] = points
    c3d["data"]["meta_points"] = {"residuals": residual.T[None]}
    _write(path, lambda p: c3d.write(str(p)))


def read_c3d(path: Path) -> tuple[np.ndarray, list[str], float, np.ndarray]:
    """xyz (frame, marker, 3) mm, labels, rate, residuals (frame, marker) of a C3D file."""
    import ezc3d

    c3d = ezc3d.c3d(str(path))
    points = c3d["data"]["points"][:3].transpose(2, 1, 0)
    return (points, list(c3d["parameters"]["POINT"]["LABELS"]["value"]),
            float(c3d["parameters"]["POINT"]["RATE"]["value"][0]), c3d["data"]["meta_points"]["residuals"][0].T)


def write_trc(markers: xr.Dataset, path: Path) -> None:
    xyz, names, fps, _ = _arrays(markers)
    n_frames = xyz.shape[0]
    lines = [f"PathFileType\t4\t(X/Y/Z)\t{path.name}",
             "DataRate\tCameraRate\tNumFrames\tNumMarkers\tUnits\tOrigDataRate\tOrigDataStartFrame\tOrigNumFrames\tUpAxis",
             f"{fps:.2f}\t{fps:.2f}\t{n_frames}\t{len(names)}\tmm\t{fps:.2f}\t1\t{n_frames}\tZ",
             "Frame#\tTime\t" + "\t".join(f"{n}\t\t" for n in names).rstrip("\t"),
             "\t\t" + "\t".join(f"X{i}\tY{i}\tZ{i}" for i in range(1, len(names) + 1))]
    frames = markers["frame"].values
    for i in range(n_frames):
        values = "\t".join("" if np.isnan(v) else f"{v:.3f}" for v in xyz[i].ravel())
        lines.append(f"{int(frames[i]) + 1}\t{frames[i] / fps:.5f}\t{values}")
    _write(path, lambda p: p.write_text("\n".join(lines) + "\n"))


def read_trc(path: Path) -> tuple[np.ndarray, list[str], float]:
    """xyz (frame, marker, 3) mm, labels and rate of a TRC file written by :func:`write_trc`."""
    rows = path.read_text().splitlines()
    header = dict(zip(rows[1].split("\t"), rows[2].split("\t")))
    names = [n for n in rows[3].split("\t")[2:] if n]
    data = [[float(v) if v else np.nan for v in row.split("\t")[2:]] for row in rows[5:] if row.strip()]
    return np.array(data).reshape(len(data), len(names), 3), names, float(header["DataRate"])


def _filled(poses: xr.Dataset) -> tuple[np.ndarray, np.ndarray]:
    """Local rotations (frame, joint, 4) and root positions (frame, 3), unsolved frames held from the nearest solved."""
    quat = poses["rotation"].transpose("frame", "joint", "quat").values.astype(np.float64)
    root = poses["position"].transpose("frame", "joint", "xyz").values[:, 0].astype(np.float64)
    solved = np.isfinite(quat).all(axis=(1, 2)) & np.isfinite(root).all(axis=1)
    if not solved.any():
        raise InputError("the poses hold no solved frame; nothing to write as BVH (check the markers and skeleton stages)")
    nearest = np.flatnonzero(solved)[np.abs(np.arange(len(solved))[:, None] - np.flatnonzero(solved)).argmin(axis=1)]
    return quat[nearest], root[nearest]


def bvh_text(poses: xr.Dataset) -> str:
    """BVH text (Y up, centimetres) of solved poses on their skeleton."""
    names = [str(n) for n in poses["joint"].values]
    offsets = poses["offset"].transpose("joint", "xyz").values.astype(np.float64) @ Z_UP_TO_Y_UP.T * BVH_SCALE
    parents = _parents(poses)
    quat, root = _filled(poses)
    children = {j: [c for c in range(len(names)) if parents[c] == j] for j in range(len(names))}
    lines, order = ["HIERARCHY"], []  # order: joints as the hierarchy lists them, the MOTION column order

    def emit(j: int, depth: int) -> None:
        order.append(j)
        pad = "  " * depth
        kind = "ROOT" if parents[j] < 0 else "JOINT"
        chans = "6 Xposition Yposition Zposition Zrotation Xrotation Yrotation" if parents[j] < 0 else \
            "3 Zrotation Xrotation Yrotation"
        lines.extend([f"{pad}{kind} {names[j]}", f"{pad}{{", f"{pad}  OFFSET {_xyz(offsets[j])}",
                      f"{pad}  CHANNELS {chans}"])
        for c in children[j]:
            emit(c, depth + 1)
        if not children[j]:
            lines.extend([f"{pad}  End Site", f"{pad}  {{", f"{pad}    OFFSET {_xyz(0.3 * offsets[j])}", f"{pad}  }}"])
        lines.append(f"{pad}}}")

    emit(int(np.flatnonzero(parents < 0)[0]), 0)
    local = Z_UP_TO_Y_UP @ Rotation.from_quat(quat.reshape(-1, 4)).as_matrix() @ Z_UP_TO_Y_UP.T
    euler = Rotation.from_matrix(local).as_euler("ZXY", degrees=True).reshape(quat.shape[:2] + (3,))  # R = Rz Rx Ry
    motion = np.concatenate([root @ Z_UP_TO_Y_UP.T * BVH_SCALE, euler[:, order].reshape(len(euler), -1)], axis=1)
    fps = float(poses.attrs["fps"])
    lines += ["MOTION", f"Frames: {len(motion)}", f"Frame Time: {1.0 / fps:.8f}"]
    lines += [" ".join(f"{v:.5f}" for v in row) for row in motion]
    return "\n".join(lines) + "\n"


def _parents(poses: xr.Dataset) -> np.ndarray:
    names = [str(n) for n in poses["joint"].values]
    if names != list(JOINT_NAMES):
        raise InputError(f"poses joints {names} are not the template's {list(JOINT_NAMES)}; BVH export needs the template")
    return PARENTS


def _xyz(v: np.ndarray) -> str:
    return " ".join(f"{x:.5f}" for x in v)


def write_bvh(poses: xr.Dataset, path: Path) -> None:
    text = bvh_text(poses)
    _write(path, lambda p: p.write_text(text))


def read_bvh_joints(path: Path) -> tuple[np.ndarray, list[str], float]:
    """World joint positions (frame, joint, 3) in metres, Z up, of a BVH file, its joint names (no End Sites), rate."""
    bvh = parse_bvh(path.read_text())
    _, pos = bvh.forward_kinematics()
    keep = [i for i, n in enumerate(bvh.names) if not n.endswith("_End")]
    return pos[:, keep] @ Z_UP_TO_Y_UP / BVH_SCALE, [bvh.names[i] for i in keep], bvh.fps  # row @ M = M^T p


def _write(path: Path, write) -> None:
    if path.suffix.lower() not in (".c3d", ".trc", ".bvh"):
        raise InputError(f"export file {path} must end in .c3d, .trc or .bvh")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_name(path.name + ".partial" + path.suffix)
        write(tmp)
        tmp.replace(path)
    except OSError as exc:
        raise StorageError(f"cannot write {path}: {exc.strerror}; choose another --out") from exc


WRITERS = {"c3d": write_c3d, "trc": write_trc, "bvh": write_bvh}
SCHEMAS = {"c3d": ("smoothed_markers", "markers3d"), "trc": ("smoothed_markers", "markers3d"), "bvh": ("poses",)}


def export_files(catalog, sequences: str | None, fmt: str, stage: str | None, out_dir: Path,
                 workers: int, processes: bool = True) -> list[Path]:
    """Write ``<out_dir>/<sequence>.<fmt>`` for every sequence of ``stage`` (computing missing partitions first
    on ``workers`` local worker processes, or threads)."""
    from mocapflow.pipeline.scheduler import compute_missing

    stage = stage or next((s for schema in SCHEMAS[fmt] if (s := stage_writing(catalog, schema))), None)
    if stage not in catalog.stages:
        raise PlanError(f"no stage {stage!r} to export as {fmt} (it needs one writing {' or '.join(SCHEMAS[fmt])}); "
                        f"the catalog's stages: {list(catalog.stages)}")
    output = catalog.stages[stage].spec.output
    if output not in SCHEMAS[fmt]:
        raise PlanError(f"stage {stage!r} writes {output}; {fmt} exports {' or '.join(SCHEMAS[fmt])} — "
                        "pick another --stage")
    store = Store(catalog.root)
    plan = build_plan(catalog, sequences)
    compute_missing(select(plan, catalog, store, only=None, until=stage), store, workers=workers, processes=processes,
                    what="cannot export")
    written = []
    for item in plan.for_stages([stage]):
        path = _inside(out_dir, f"{item.partition.sequence}.{fmt}")
        WRITERS[fmt](store.open(stage, item.key, item.stage.schema).load(), path)
        written.append(path)
    return written


def _inside(out_dir: Path, name: str) -> Path:
    """``out_dir / name``, refused unless it is a file directly inside ``out_dir``."""
    path = out_dir / name
    if path.resolve().parent != out_dir.resolve() or Path(name).name != name:
        raise PlanError(f"export file name {name!r} would be written outside --out {out_dir}; a sequence id must be a "
                        "plain name (see the naming rule in the README): rename the sequence")
    return path

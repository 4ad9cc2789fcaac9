"""`mocapflow export` for UUO's solved bodies (stages writing ``uuo_body``): labelled markers, the solved skeleton,
a report page.

- C3D: the take's trajectories (the stage's markers input, millimetres, Z up as every C3D of mocapflow), each
  labelled by the solve: ``<part>_v<vertex>`` (``left_thigh_v04321``: the body part and Anny vertex the
  trajectory was given), an unlabelled one (a ghost, or a marker off the matched chain) by its trajectory id.
  POINT:DESCRIPTIONS keeps each trajectory's id. Point residuals are 0 (solved data, no measurement residual),
  -1 where a trajectory has no sample.
- BVH: Anny's whole rig as solved (every bone, the phenotype's rest offsets), in the BVH convention of
  formats/bvh.py (Y up, facing +Z, centimetres, ZXY rotations). A bone's BVH rotation is its world rotation
  from its rest orientation relative to its parent's, so the file's forward kinematics give the solved bone
  heads exactly.
- report: ``<sequence>/report.html`` with PNGs: the markers on the solved mesh from the front and the side of one
  frame, the error per joint and the error over time, against the studio's truth when the take has it, else
  against the catalog's labelled reference (``evaluation.uuo_reference``), else without the error figures.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import xarray as xr
from scipy.spatial.transform import Rotation

from mocapflow.formats import bvh, c3d
from mocapflow.pipeline.catalog import stage_writing
from mocapflow.pipeline.export import UNIT_SCALE, target, write_atomically
from mocapflow.pipeline.registry import ExportJob, Exporter
from mocapflow.presentation.report import FONT, WHITE, bar_chart, colour, line_plot, write_html, write_png
from mocapflow.tasks.shared.body import JOINT_NAMES
from mocapflow.tasks.shared.mesh_body import PARTS, Phenotype, mesh_body, pose_mesh

UNLABELLED = ""


def marker_labels(solved: xr.Dataset) -> list[str]:
    """Each trajectory's C3D label: ``<part>_v<vertex>`` where the solve gave it a vertex, else its id."""
    return [f"{part}_v{int(v):05d}" if v >= 0 else str(m)
            for m, v, part in zip(solved["marker"].values, solved["vertex"].values, solved["part"].values)]


def write_uuo_c3d(solved: xr.Dataset, markers: xr.Dataset, path: Path) -> None:
    """The take's trajectories labelled by the solve, as a float C3D (see the module's text)."""
    xyz = markers["position"].transpose("frame", "marker", "xyz").values.astype(np.float64) * UNIT_SCALE
    if list(markers["marker"].values) != list(solved["marker"].values):
        raise ValueError("the solve's trajectories are not its markers input's")  # internal: the stage's own input
    word4 = np.where(np.isfinite(xyz).all(-1), 0, -1)
    scale = c3d.c3d_scale(xyz, np.zeros(xyz.shape[:2]))
    names = marker_labels(solved)
    ids = [str(m) for m in markers["marker"].values]

    write_atomically(path, lambda p: c3d.write_points(p, xyz, names, float(markers.attrs["fps"]), scale, word4,
                                                     descriptions=ids), ".c3d")


def rig_bvh_text(solved: xr.Dataset) -> str:
    """BVH text of the solved Anny rig (see the module's text)."""
    return bvh.anny_rig_bvh(mesh_body(Phenotype(**solved.attrs["phenotype"])), solved["bone_rotation"].values,
                            solved["root"].values, float(solved.attrs["fps"]))


def write_uuo_bvh(solved: xr.Dataset, path: Path) -> None:
    text = rig_bvh_text(solved)
    write_atomically(path, lambda p: p.write_text(text), ".bvh")


def mesh_view(vertices: np.ndarray, faces: np.ndarray, markers: np.ndarray, marker_parts: list[str], axes: str,
              title: str, size: int = 420) -> np.ndarray:
    """One frame's solved mesh (painter's algorithm, Lambert shading) and its markers (coloured by the part they
    were given; white rings: unlabelled; every marker drawn, hidden or not), orthographic from the body's front
    (``"xz"``: the viewer on +Y, where the studio's bodies face) or its left side (``"yz"``: the viewer on -X).
    vertices (vertex, 3), faces (face, 3), markers (marker, 3)"""
    # the axis across the image, its direction (the viewer's right), the axis toward the viewer and its sign
    h_axis, h_sign, depth_axis, toward_sign = (0, -1.0, 1, 1.0) if axes == "xz" else (1, -1.0, 0, -1.0)
    centre = vertices.mean(axis=0)
    scale = size / 2.2  # a 2.2 m field of view

    def px(p: np.ndarray) -> np.ndarray:
        return np.stack([size / 2 + h_sign * (p[..., h_axis] - centre[h_axis]) * scale,
                         size / 2 - (p[..., 2] - centre[2]) * scale], -1)

    img = np.full((size, size, 3), 30, np.uint8)
    tri = vertices[faces]  # (face, 3, 3)
    normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    normal /= np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), 1e-12)
    toward = np.zeros(3)
    toward[depth_axis] = toward_sign  # toward the viewer
    shade = np.abs(normal @ toward)
    depth = tri[:, :, depth_axis].mean(axis=1) * toward[depth_axis]
    corners = px(tri).astype(np.int32)
    for f in np.argsort(depth):  # far faces first
        grey = int(60 + 170 * shade[f])
        cv2.fillConvexPoly(img, corners[f], (grey, grey, grey), cv2.LINE_AA)
    parts = sorted(PARTS["body"])
    for p, part in zip(px(markers), marker_parts):
        if not np.isfinite(p).all():
            continue
        at = tuple(int(v) for v in p)
        if part == UNLABELLED:
            cv2.circle(img, at, 4, WHITE, 1, cv2.LINE_AA)
        else:
            cv2.circle(img, at, 4, colour(parts.index(part) if part in parts else 0, len(parts)), -1, cv2.LINE_AA)
    cv2.putText(img, title, (8, 18), FONT, 0.45, WHITE, 1, cv2.LINE_AA)
    return img


def report_figures(folder: Path, solved: xr.Dataset, markers: xr.Dataset, truth: np.ndarray | None,
                   against: str, tag: str = "") -> list[Path]:
    """The report's PNGs for one take; ``truth`` (frame, joint, 3) what the joints are scored against, if any;
    ``tag`` ends each file's name (``markers_on_mesh{tag}.png``: one set per take in one folder)."""
    folder.mkdir(parents=True, exist_ok=True)
    frame = solved.sizes["frame"] // 2
    body = mesh_body(Phenotype(**solved.attrs["phenotype"]))
    rotations = Rotation.from_quat(solved["bone_rotation"].values[frame].reshape(-1, 4)).as_matrix()[None]
    vertices = pose_mesh(body, rotations, solved["root"].values[frame][None].astype(np.float64)).vertices[0]
    faces = body.faces[body.skin]
    positions = markers["position"].transpose("frame", "marker", "xyz").values[frame].astype(np.float64)
    parts = [str(p) for p in solved["part"].values]
    out = [folder / f"markers_on_mesh{tag}.png"]
    write_png(out[0], np.hstack([mesh_view(vertices, faces, positions, parts, "xz", f"front, frame {frame}"),
                                 mesh_view(vertices, faces, positions, parts, "yz", f"left side, frame {frame}")]))
    if truth is not None:
        error = np.linalg.norm(solved["joints"].values.astype(np.float64) - truth, axis=-1) * 1000.0  # (frame, joint)
        out += [folder / f"joint_errors{tag}.png", folder / f"error_over_time{tag}.png"]
        write_png(out[1], bar_chart(dict(zip(JOINT_NAMES, error.mean(axis=0))),
                                    title=f"mean error per joint against {against}", unit="mm", size=(640, 560)))
        frames = np.arange(len(error), dtype=float)
        write_png(out[2], line_plot(frames, {"mean over joints": error.mean(axis=1), "worst joint": error.max(axis=1)},
                                    title=f"joint error against {against}", xlabel="frame", ylabel="mm",
                                    y_max=float(max(np.ceil(error.max() / 50.0) * 50.0, 50.0))))
    return out


def write_report(folder: Path, sequence: str, stage: str, solved: xr.Dataset, markers: xr.Dataset,
                 truth: np.ndarray | None, against: str, files: list[Path]) -> Path:
    """``folder/report.html`` and its PNGs for one take's solve."""
    images = report_figures(folder, solved, markers, truth, against)
    labelled = solved["vertex"].values >= 0
    summary = {"sequence": sequence, "stage": stage, "frames": solved.sizes["frame"],
               "trajectories": solved.sizes["marker"], "labelled": f"{labelled.mean():.0%}",
               "root yaw hypothesis (deg)": float(solved.attrs.get("yaw_deg", np.nan)),
               "parts": ", ".join(solved.attrs.get("parts", []))}
    lines = [f"{'trajectory':12s} {'label':24s} mean distance to its vertex (mm)"]
    lines += [f"{str(m):12s} {label:24s} {1000 * d:.1f}" for m, label, d in
              zip(solved["marker"].values, marker_labels(solved), solved["marker_distance"].values)]
    if truth is not None:
        error = np.linalg.norm(solved["joints"].values.astype(np.float64) - truth, axis=-1)
        summary[f"MPJPE against {against} (mm)"] = float(1000 * error.mean())
    page = folder / "report.html"
    write_html(page, title=f"UUO solve of {sequence} ({stage})", summary=summary, table="\n".join(lines),
               images=images, files=files)
    return page


# ---- the exporters ----------------------------------------------------------------------------------------------

def default_stage(catalog) -> str | None:
    """The first UUO solve that chooses among hypotheses (the headline one of `mocapflow evaluate`)."""
    return next((s.name for s in catalog.stages.values() if s.spec.output == "uuo_body"
                 and "uuo_body" in s.spec.inputs.values()), None)


def _markers(job: ExportJob) -> xr.Dataset:
    return solve_markers(job.catalog, job.plan, job.store, job.stage, job.sequence)


def export_c3d(job: ExportJob) -> list[Path]:
    path = target(job.out_dir, f"{job.sequence}.c3d")
    write_uuo_c3d(job.data, _markers(job), path)
    return [path]


def export_bvh(job: ExportJob) -> list[Path]:
    path = target(job.out_dir, f"{job.sequence}.bvh")
    write_uuo_bvh(job.data, path)
    return [path]


def report_needs(catalog, stage: str) -> list[str]:
    """The labelled reference a recorded take's report is scored against, where the catalog names one."""
    reference = catalog.evaluation.get("uuo_reference")
    return [str(reference)] if reference in catalog.stages else []


def solve_truth(catalog, plan, store, stage: str, sequence: str) -> tuple[np.ndarray | None, str]:
    """What ``stage``'s joints of ``sequence`` are scored against, (frame, joint, 3) m, and its name: the studio's
    truth where the take has it, else the catalog's labelled reference (``evaluation.uuo_reference``), else none."""
    raw_stage = stage_writing(catalog, "raw_markers")
    raw = plan.open(store, raw_stage, sequence) if raw_stage else None
    reference = catalog.evaluation.get("uuo_reference")
    if raw is not None and "gt_joints" in raw:
        return raw["gt_joints"].values.astype(np.float64), "the studio's truth"
    if reference in catalog.stages and reference != stage:
        truth = plan.open(store, str(reference), sequence)["joints"].values.astype(np.float64)
        return truth, f"the labelled reference ({reference})"
    return None, ""


def solve_markers(catalog, plan, store, stage: str, sequence: str) -> xr.Dataset:
    """The trajectories the solve ``stage`` labelled: its ``markers`` input."""
    return plan.open(store, catalog.stages[stage].inputs["markers"], sequence).load()


def export_report(job: ExportJob) -> list[Path]:
    """``<out>/<sequence>/report.html``: against the studio's truth where the take has it, else the labelled reference."""
    truth, against = solve_truth(job.catalog, job.plan, job.store, job.stage, job.sequence)
    folder = target(job.out_dir, job.sequence)
    return [write_report(folder, job.sequence, job.stage, job.data, _markers(job), truth, against, files=[])]


EXPORTERS = (
    Exporter("c3d", ("uuo_body",), export_c3d, default_stage=default_stage),
    Exporter("bvh", ("uuo_body",), export_bvh, default_stage=default_stage),
    Exporter("report", ("uuo_body",), export_report, default_stage=default_stage, needs=report_needs),
)

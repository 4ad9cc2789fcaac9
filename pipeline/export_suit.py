"""`mocapflow export` of the checkerboard suit: its labelled corners per frame as C3D (one point per corner, named by
its first key: the code of a coded square it belongs to and its place k = 0-3 in that square, e.g. ``AB2``), and the
filled suit as one PLY mesh per frame (the corners as vertices with an ``observed`` flag, the corner mesh's cells
split into triangles).

C3D: millimetres, Z up, floats, as pipeline/export.py writes markers; a corner the stage has no position for is
missing (residual -1); a filled corner (suit_filled, not observed in that frame) has residual 0, the C3D
convention for interpolated data, and an observed one residual 1 with no camera bits (the triangulation's own
error is in the artifact). PLY (ASCII, metres, Z up) goes to ``<out>/<sequence>/frame_<number>.ply``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import xarray as xr

from mocapflow.pipeline.errors import PlanError, StorageError
from mocapflow.pipeline.export import SUIT_SCHEMAS, UNIT_SCALE, _inside, _write, _write_c3d, c3d_scale

__all__ = ["SUIT_SCHEMAS", "corner_names", "export_suit", "ply_text", "write_suit_c3d", "write_suit_ply"]


def corner_names(codes, square_corners: np.ndarray, n_corners: int) -> list[str]:
    """Each corner's first key as a name: code + quad vertex (``AB2``)."""
    names = [""] * n_corners
    for code, row in zip(codes, square_corners):
        for k, c in enumerate(row):
            names[c] = names[c] or f"{code}{k}"
    return names


def write_suit_c3d(points: xr.Dataset, names: list[str], path: Path) -> None:
    xyz = points["position"].transpose("frame", "corner", "xyz").values.astype(np.float64) * UNIT_SCALE
    seen = np.isfinite(xyz).all(axis=-1)
    observed = points["observed"].values if "observed" in points else seen
    residual = np.where(seen, np.where(observed, 1.0, 0.0), -1.0)  # (frame, corner)
    scale = c3d_scale(xyz, residual)
    word4 = np.where(residual < 0, -1.0, residual)
    _write(path, lambda p: _write_c3d(p, np.where(seen[..., None], xyz, 0.0), names, float(points.attrs["fps"]), scale,
                                      word4))


def ply_text(position: np.ndarray, observed: np.ndarray, cells: np.ndarray) -> str:
    """One frame of the filled suit: position (corner, 3) m, observed (corner,), cells (cell, 4) counter-clockwise
    in uv -> ASCII PLY with the cells split into two triangles each."""
    tris = np.concatenate([cells[:, [0, 1, 2]], cells[:, [0, 2, 3]]])
    lines = ["ply", "format ascii 1.0", "comment mocapflow: the filled checkerboard suit, metres, Z up",
             f"element vertex {len(position)}", "property float x", "property float y", "property float z",
             "property uchar observed", f"element face {len(tris)}", "property list uchar int vertex_indices",
             "end_header"]
    lines += [f"{x:.6f} {y:.6f} {z:.6f} {int(o)}" for (x, y, z), o in zip(position, observed)]
    lines += [f"3 {a} {b} {c}" for a, b, c in tris]
    return "\n".join(lines) + "\n"


def write_suit_ply(filled: xr.Dataset, cells: np.ndarray, folder: Path) -> list[Path]:
    position = filled["position"].transpose("frame", "corner", "xyz").values
    if not np.isfinite(position).all():
        raise PlanError(f"the filled suit for {folder.name} has missing corners; export suit_filled (every corner "
                        "filled), not suit_points, as PLY")
    written = []
    try:
        folder.mkdir(parents=True, exist_ok=True)
        for f, frame in enumerate(filled["frame"].values):
            path = folder / f"frame_{int(frame):06d}.ply"
            tmp = path.with_name(path.name + ".partial")
            tmp.write_text(ply_text(position[f], filled["observed"].values[f], cells))
            tmp.replace(path)
            written.append(path)
    except OSError as exc:
        raise StorageError(f"cannot write {folder}: {exc.strerror}; choose another --out") from exc
    return written


def export_suit(plan, store, images_stage: str, stage: str, fmt: str, out_dir: Path) -> list[Path]:
    """Write every sequence of the suit ``stage`` as ``fmt`` (c3d or ply); the pattern comes from ``images_stage``."""
    written = []
    for item in plan.for_stages([stage]):
        seq = item.partition.sequence
        pattern = plan.open(store, images_stage, seq)[["code", "square_corners", "cells", "corner_face"]]
        data = store.open(stage, item.key, item.stage.schema).load()
        if fmt == "c3d":
            names = corner_names([str(c) for c in pattern["code"].values], pattern["square_corners"].values,
                                 pattern.sizes["corner"])
            path = _inside(out_dir, f"{seq}.c3d")
            write_suit_c3d(data, names, path)
            written.append(path)
        else:
            written += write_suit_ply(data, pattern["cells"].values, _inside(out_dir, seq))
    return written

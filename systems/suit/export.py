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
from mocapflow.formats import c3d, ply
from mocapflow.pipeline.catalog import stage_writing
from mocapflow.pipeline.export import UNIT_SCALE, target, write_atomically
from mocapflow.pipeline.registry import ExportJob, Exporter

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
    scale = c3d.c3d_scale(xyz, residual)
    word4 = np.where(residual < 0, -1.0, residual)
    write_atomically(path, lambda p: c3d.write_points(p, np.where(seen[..., None], xyz, 0.0), names,
                                                     float(points.attrs["fps"]), scale, word4), ".c3d")


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
            tmp.write_text(ply.ply_text(position[f], filled["observed"].values[f], cells))
            tmp.replace(path)
            written.append(path)
    except OSError as exc:
        raise StorageError(f"cannot write {folder}: {exc.strerror}; choose another --out") from exc
    return written


def _pattern(job: ExportJob) -> xr.Dataset:
    """The suit's print (codes, squares, cells) from the catalog's images stage."""
    images = stage_writing(job.catalog, "suit_images")
    if images is None:
        raise PlanError("the catalog has suit stages but no stage writing suit_images, whose print names the corners")
    return job.plan.open(job.store, images, job.sequence)[["code", "square_corners", "cells", "corner_face"]]


def export_c3d(job: ExportJob) -> list[Path]:
    """The corners (observed or filled) labelled code + quad vertex, as a float C3D."""
    pattern = _pattern(job)
    names = corner_names([str(c) for c in pattern["code"].values], pattern["square_corners"].values,
                         pattern.sizes["corner"])
    path = target(job.out_dir, f"{job.sequence}.c3d")
    write_suit_c3d(job.data, names, path)
    return [path]


def export_ply(job: ExportJob) -> list[Path]:
    """The filled suit as one PLY mesh per frame, ``<out>/<sequence>/frame_NNNNNN.ply``."""
    return write_suit_ply(job.data, _pattern(job)["cells"].values, target(job.out_dir, job.sequence))


def _last_writing(*schemas: str):
    def find(catalog) -> str | None:
        return next((s for schema in schemas if (s := stage_writing(catalog, schema))), None)
    return find


EXPORTERS = (
    Exporter("c3d", ("suit_filled", "suit_points"), export_c3d, default_stage=_last_writing("suit_filled", "suit_points")),
    Exporter("ply", ("suit_filled",), export_ply, default_stage=_last_writing("suit_filled")),
)

"""Marker files in: C3D (through ezc3d) and TRC, as raw-marker datasets on the shared axes (metres, Z up).

    ds = read_markers(path, up="z", labels="ignore")      # -> schema raw_markers: position (frame, marker, xyz)

Units come from the file (C3D ``POINT:UNITS``, TRC ``Units``), the frame rate too (``POINT:RATE``, ``DataRate``).
Files do not say which way is up, so ``up`` does: ``"z"`` keeps the axes, ``"y"`` turns a Y-up file onto the
project's Z up by a proper rotation (x stays, y becomes up: (x, y, z) -> (x, -z, y)). A sample the file marks
missing (a negative C3D residual, an empty TRC cell, or NaN) is NaN. With ``labels="ignore"`` the trajectories
are ``m000``, ``m001``, ... in file order and the file's labels are dropped (an unlabelled take); with ``"use"``
they keep the file's labels, a label that repeats (one marker split over several trajectories) getting
``#2``, ``#3`` ... Trajectories that are never seen are kept: a fragmented or ghost-ridden recording is
read as it is.
"""

from __future__ import annotations

from collections import Counter
from pathlib import Path

import numpy as np
import xarray as xr

from mocapflow.pipeline.errors import InputError
from mocapflow.tasks.shared.kinematics import Y_UP_TO_Z_UP

UNITS_M = {"mm": 0.001, "cm": 0.01, "m": 1.0, "dm": 0.1, "in": 0.0254}
UPS = ("z", "y")
LABELS = ("ignore", "use")


def read_markers(path: Path, *, up: str = "z", labels: str = "ignore") -> xr.Dataset:
    """A C3D or TRC file's marker trajectories in the raw_markers schema (metres, Z up)."""
    path = Path(path)
    if up not in UPS:
        raise InputError(f"{path}: up axis {up!r} is not one of {', '.join(UPS)}; say which axis of the file is up")
    if labels not in LABELS:
        raise InputError(f"{path}: labels {labels!r} is not one of {', '.join(LABELS)}")
    readers = {".c3d": _c3d, ".trc": _trc}
    reader = readers.get(path.suffix.lower())
    if reader is None:
        raise InputError(f"{path}: not a marker file this reads ({', '.join(readers)}); export C3D or TRC")
    positions, fps, names, unit = reader(path)  # (frame, marker, 3) in the file's units and axes
    if unit not in UNITS_M:
        raise InputError(f"{path}: unknown length unit {unit!r}; known: {', '.join(UNITS_M)}")
    if not (np.isfinite(fps) and fps > 0):
        raise InputError(f"{path}: frame rate {fps} is not a positive number; fix the file's rate")
    positions = positions * UNITS_M[unit]
    if up == "y":
        positions = positions @ Y_UP_TO_Z_UP.T
    return _dataset(positions, fps, names, labels)


def _dataset(positions: np.ndarray, fps: float, names: list[str], labels: str) -> xr.Dataset:
    n_frames, n_markers, _ = positions.shape
    ids = [f"m{i:03d}" for i in range(n_markers)] if labels == "ignore" else _unique(names)
    data = {"position": (("frame", "marker", "xyz"), positions.astype(np.float32)),
            "timestamp": (("frame",), np.arange(n_frames) / fps)}
    if labels == "use":
        data["label"] = (("marker",), np.array(names, dtype=object))
    return xr.Dataset(data, coords={"frame": np.arange(n_frames, dtype=np.int64),
                                    "marker": np.array(ids, dtype=object),
                                    "xyz": np.array(["x", "y", "z"], dtype=object)},
                      attrs={"fps": float(fps), "length_unit": "m", "up_axis": "Z"})


def _unique(names: list[str]) -> list[str]:
    """Labels made distinct: a repeated label's later trajectories get #2, #3, ..."""
    seen: Counter = Counter()
    out = []
    for name in names:
        seen[name] += 1
        out.append(name if seen[name] == 1 else f"{name}#{seen[name]}")
    return out


def _c3d(path: Path) -> tuple[np.ndarray, float, list[str], str]:
    import ezc3d

    try:
        c3d = ezc3d.c3d(str(path))
    except (RuntimeError, ValueError, OSError) as exc:
        raise InputError(f"{path}: not a readable C3D file ({exc})") from exc
    point = c3d["parameters"]["POINT"]
    points = np.asarray(c3d["data"]["points"][:3], np.float64).transpose(2, 1, 0)  # (frame, marker, 3)
    residuals = np.asarray(c3d["data"]["meta_points"]["residuals"][0]).T  # (frame, marker)
    points[residuals < 0] = np.nan
    names = [str(n).strip() for n in point["LABELS"]["value"]][:points.shape[1]]
    names += [f"unlabelled{i}" for i in range(len(names), points.shape[1])]
    unit = str(point["UNITS"]["value"][0]).strip().lower() if point.get("UNITS") else "mm"
    return points, float(c3d["header"]["points"]["frame_rate"]), names, unit


def _trc(path: Path) -> tuple[np.ndarray, float, list[str], str]:
    try:
        lines = path.read_text().splitlines()
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"{path}: cannot read the TRC file ({exc})") from exc
    if len(lines) < 5:
        raise InputError(f"{path}: a TRC file needs its 5 header lines; this has {len(lines)} lines")
    keys, values = lines[1].split("\t"), lines[2].split("\t")
    header = dict(zip((k.strip() for k in keys), (v.strip() for v in values)))
    try:
        fps = float(header["DataRate"])
        unit = header["Units"].lower()
    except (KeyError, ValueError) as exc:
        raise InputError(f"{path}: TRC header line 3 needs DataRate and Units ({exc})") from exc
    names = [n.strip() for n in lines[3].split("\t")[2:] if n.strip()]
    rows = [line.split("\t") for line in lines[5:] if line.strip()]
    points = np.full((len(rows), len(names), 3), np.nan)
    for f, row in enumerate(rows):
        cells = row[2:2 + 3 * len(names)]
        for k, cell in enumerate(cells):
            if cell.strip():
                try:
                    points[f, k // 3, k % 3] = float(cell)
                except ValueError as exc:
                    raise InputError(f"{path}: line {f + 6}: {cell!r} is not a number") from exc
    return points, fps, names, unit

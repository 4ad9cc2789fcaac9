"""Marker files in: C3D (through ezc3d) and TRC, as raw-marker datasets on the shared axes (metres, Z up).

    ds = read_markers(path, up="z", labels="ignore")      # -> schema raw_markers: position (frame, marker, xyz)

Units come from the file (C3D ``POINT:UNITS``, TRC ``Units``), the frame rate too (``POINT:RATE``, ``DataRate``).
Files do not say which way is up, so ``up`` does: ``"z"`` keeps the axes, ``"y"`` turns a Y-up file onto the
project's Z up by a proper rotation (x stays, y becomes up: (x, y, z) -> (x, -z, y)), and ``"auto"`` (the
default) finds it from the markers (``up_from_data``: the body's tall axis, whose lowest point keeps to the
floor). A sample the file marks missing (a negative C3D residual, an empty TRC cell, or NaN) is NaN. With
``labels="ignore"`` the trajectories are ``m000``, ``m001``, ... in file order and the file's labels are
dropped (an unlabelled take); with ``"use"``
they keep the file's labels, a label that repeats (one marker split over several trajectories) getting
``#2``, ``#3`` ... Trajectories that are never seen are kept: a fragmented or ghost-ridden recording is
read as it is. A file cut short, a damaged sample, a file with no sample, or a coordinate farther from the origin
than ``max_coordinate_m`` (20 m; no capture volume is larger) is refused, naming the frame and marker.
"""

from __future__ import annotations

from collections import Counter
from pathlib import Path

import numpy as np
import xarray as xr

from mocapflow.formats import c3d, trc
from mocapflow.pipeline.errors import InputError
from mocapflow.tasks.shared.kinematics import Y_UP_TO_Z_UP

UNITS_M = {"mm": 0.001, "cm": 0.01, "m": 1.0, "dm": 0.1, "in": 0.0254}
UPS = ("auto", "z", "y")
LABELS = ("ignore", "use")
MAX_COORDINATE_M = 20.0  # metres from the origin on any axis: larger than any capture volume (the catalog's
# max_coordinate_m of a markers dataset changes it)


def up_from_data(positions: np.ndarray) -> str:
    """Which axis of a recording is up, z or y, from the markers themselves: a person's markers spread farthest
    along the vertical (a body, standing or seated, is taller than it is deep), and their lowest point keeps to
    the floor while the body moves about; the axis of the larger spread / (1 m + drift of the lowest point)
    wins (the drift only a mild correction: a marker lost at the feet moves the lowest point too).
    positions (frame, marker, 3) NaN where unseen -> "z" | "y" """
    score = {}
    for name, axis in (("y", 1), ("z", 2)):
        values = positions[..., axis]
        seen = np.isfinite(values).any(axis=1)
        if not seen.any():
            return "z"
        with np.errstate(all="ignore"):
            spread = np.nanmedian(np.nanmax(values[seen], axis=1) - np.nanmin(values[seen], axis=1))
            floor = np.nanmin(values[seen], axis=1)
        drift = np.nanpercentile(floor, 90) - np.nanpercentile(floor, 10)
        score[name] = spread / (drift + 1.0)
    return "y" if score["y"] > score["z"] else "z"


def read_markers(path: Path, *, up: str = "auto", labels: str = "ignore",
                 max_coordinate_m: float = MAX_COORDINATE_M) -> xr.Dataset:
    """A C3D or TRC file's marker trajectories in the raw_markers schema (metres, Z up). A file with no sample at
    all, or a coordinate farther than ``max_coordinate_m`` from the origin on any axis, is refused."""
    path = Path(path)
    if up not in UPS:
        raise InputError(f"{path}: up axis {up!r} is not one of {', '.join(UPS)}; say which axis of the file is up")
    if labels not in LABELS:
        raise InputError(f"{path}: labels {labels!r} is not one of {', '.join(LABELS)}")
    readers = {".c3d": c3d.read_trajectories, ".trc": trc.read_trajectories}
    reader = readers.get(path.suffix.lower())
    if reader is None:
        raise InputError(f"{path}: not a marker file this reads ({', '.join(readers)}); export C3D or TRC")
    positions, fps, names, unit = reader(path)  # (frame, marker, 3) in the file's units and axes
    if unit not in UNITS_M:
        raise InputError(f"{path}: unknown length unit {unit!r}; known: {', '.join(UNITS_M)}")
    if not (np.isfinite(fps) and fps > 0):
        raise InputError(f"{path}: frame rate {fps} is not a positive number; fix the file's rate")
    positions = positions * UNITS_M[unit]
    _check_samples(path, positions, names, max_coordinate_m)
    found = up_from_data(positions) if up == "auto" else up
    if found == "y":
        positions = positions @ Y_UP_TO_Z_UP.T
    ds = _dataset(positions, fps, names, labels)
    ds.attrs["file_up_axis"] = found.upper() + (" (found from the markers)" if up == "auto" else "")
    return ds


def _check_samples(path: Path, positions: np.ndarray, names: list[str], bound: float) -> None:
    """Refuse a file with no sample, or with a coordinate (metres, the file's axes) no capture volume holds."""
    if not np.isfinite(positions).any():
        raise InputError(f"{path}: none of its {positions.shape[1]} marker(s) has a sample in any of its "
                         f"{positions.shape[0]} frame(s); export the trajectories (not an empty take)")
    with np.errstate(invalid="ignore"):
        far = np.abs(positions) > bound
    if far.any():
        frame, marker, axis = (int(i) for i in np.argwhere(far)[0])
        raise InputError(f"{path}: frame {frame} marker {names[marker]}: {'xyz'[axis]} = "
                         f"{positions[frame, marker, axis]:.4g} m lies beyond {bound:g} m of the origin, outside any "
                         f"capture volume ({int(far.any(axis=-1).sum())} sample(s) so); the file is damaged or its "
                         "unit is wrong: export it again, or raise the markers dataset's max_coordinate_m")


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

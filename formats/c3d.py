"""C3D marker files (through ezc3d): writing labelled points as float data, reading them back, reading any
recording's trajectories.

The writer follows the C3D spec where ezc3d does not: POINT:SCALE is negative (floats) and of magnitude
max |coordinate| / 32000 or the largest residual / 255, whichever is larger (:func:`c3d_scale`), the header's scale
equals it, and each point's word 4 holds the camera bits in its high byte and the residual / |SCALE| in its low
byte (-1 when the point is missing).
"""

from __future__ import annotations

from pathlib import Path

import ezc3d
import numpy as np

from mocapflow.pipeline.errors import InputError


def c3d_scale(xyz: np.ndarray, residual: np.ndarray) -> float:
    """POINT:SCALE for float storage: negative (the C3D sign for floats), magnitude the larger of the spec's
    max |coordinate| / 32000 and the largest residual / 255 (the residual is one byte in units of |SCALE|)."""
    coords = np.abs(xyz[np.isfinite(xyz)])
    return -max(coords.max() / 32000.0 if coords.size else 0.0, residual.max(initial=0.0) / 255.0, 1e-3)


def write_points(path: Path, xyz: np.ndarray, names: list[str], fps: float, scale: float, word4: np.ndarray,
               descriptions: list[str] | None = None) -> None:
    """Float (Intel) C3D with the spec's point word 4 (camera bits in the high byte, residual / |SCALE| in the low
    byte, -1 when missing) and the header's scale equal to POINT:SCALE. ezc3d writes the file; word 4 and the header
    scale are then set here, as ezc3d puts the residual in the high byte of word 4 and leaves the header scale at -1."""
    c3d = ezc3d.c3d()
    c3d["parameters"]["POINT"]["RATE"]["value"] = [fps]
    c3d["parameters"]["POINT"]["LABELS"]["value"] = names
    c3d["parameters"]["POINT"]["UNITS"]["value"] = ["mm"]
    c3d["parameters"]["POINT"]["SCALE"]["value"] = [scale]
    if descriptions is not None:
        c3d["parameters"]["POINT"]["DESCRIPTIONS"]["value"] = descriptions
    c3d.add_parameter("POINT", "X_SCREEN", "+X")
    c3d.add_parameter("POINT", "Y_SCREEN", "+Z")  # Z up
    points = np.ones((4, len(names), xyz.shape[0]))
    points[:3] = xyz.transpose(2, 1, 0)  # (xyz, marker, frame)
    c3d["data"]["points"] = points
    c3d.write(str(path))
    data = bytearray(path.read_bytes())
    data[12:16] = np.float32(scale).tobytes()  # header words 7-8: POINT:SCALE
    start = (int(np.frombuffer(data, "<u2", 1, 16)[0]) - 1) * 512  # header word 9: first data block
    n = xyz.shape[0] * len(names) * 4
    block = np.frombuffer(data, "<f4", n, start).reshape(xyz.shape[0], len(names), 4).copy()
    block[..., 3] = word4
    data[start:start + 4 * n] = block.tobytes()
    path.write_bytes(bytes(data))


def read_points(path: Path) -> tuple[np.ndarray, list[str], float, np.ndarray]:
    """xyz (frame, marker, 3) mm, labels, rate, residuals (frame, marker) mm (-1 where missing) of a float C3D file
    written by :func:`write_points`. Coordinates through ezc3d; residuals decoded from point word 4 as the C3D spec
    lays it out (ezc3d reads float files' residual byte from the wrong half of the word)."""
    c3d = ezc3d.c3d(str(path))
    points = c3d["data"]["points"][:3].transpose(2, 1, 0)
    scale = float(c3d["parameters"]["POINT"]["SCALE"]["value"][0])
    data = path.read_bytes()
    start = (int(np.frombuffer(data, "<u2", 1, 16)[0]) - 1) * 512
    word4 = np.frombuffer(data, "<f4", points.size // 3 * 4, start).reshape(points.shape[:2] + (4,))[..., 3]
    word4 = word4.astype(np.int64)
    residual = np.where(word4 < 0, -1.0, (word4 & 0xFF) * abs(scale))
    return (points, list(c3d["parameters"]["POINT"]["LABELS"]["value"]),
            float(c3d["parameters"]["POINT"]["RATE"]["value"][0]), residual)


def read_trajectories(path: Path) -> tuple[np.ndarray, float, list[str], str]:
    """Any C3D file's trajectories as recorded: points (frame, marker, 3) in the file's unit and axes, NaN where
    a residual marks a sample missing, its rate, its labels (``unlabelledN`` past the last label) and its unit
    (``POINT:UNITS``, mm when absent). A file holding fewer frames than its header announces (cut short), or a
    present sample that is not a finite number (damaged bytes), is refused, naming the frame and marker."""
    try:
        c3d = ezc3d.c3d(str(path))
    except (RuntimeError, ValueError, OSError) as exc:
        raise InputError(f"{path}: not a readable C3D file ({exc})") from exc
    point = c3d["parameters"]["POINT"]
    points = np.asarray(c3d["data"]["points"][:3], np.float64).transpose(2, 1, 0)  # (frame, marker, 3)
    residuals = np.asarray(c3d["data"]["meta_points"]["residuals"][0]).T  # (frame, marker)
    present = residuals >= 0
    points[~present] = np.nan
    names = [str(n).strip() for n in point["LABELS"]["value"]][:points.shape[1]]
    names += [f"unlabelled{i}" for i in range(len(names), points.shape[1])]
    _check_frame_count(path, points.shape[0])
    _check_finite(path, points, present, names)
    unit = str(point["UNITS"]["value"][0]).strip().lower() if point.get("UNITS") else "mm"
    return points, float(c3d["header"]["points"]["frame_rate"]), names, unit


def header_frames(data: bytes) -> int:
    """The number of frames a C3D file's header announces (words 4 and 5: first and last frame), in the byte order
    of the processor its parameter section names (86: MIPS, big-endian; else little-endian)."""
    if len(data) < 10:
        return 0
    block = data[0]
    processor = data[(block - 1) * 512 + 3] if block >= 1 and len(data) > (block - 1) * 512 + 3 else 84
    first, last = np.frombuffer(data, ">u2" if processor == 86 else "<u2", 2, 6)
    return int(last) - int(first) + 1


def _check_frame_count(path: Path, n_read: int) -> None:
    """Refuse a file cut short: fewer frames read than its header announces (a header's last frame stops at 65535,
    so a longer file reads more, never fewer)."""
    announced = header_frames(path.read_bytes()[:64 * 1024])
    if n_read < announced:
        raise InputError(f"{path}: holds {n_read} of the {announced} frames its header announces (the file is cut "
                         "short or damaged); copy or export it again")


def _check_finite(path: Path, points: np.ndarray, present: np.ndarray, names: list[str]) -> None:
    """Refuse a sample its residual marks present whose coordinates are not finite numbers (damaged bytes)."""
    bad = present & ~np.isfinite(points).all(axis=-1)
    if bad.any():
        frame, marker = (int(i) for i in np.argwhere(bad)[0])
        raise InputError(f"{path}: frame {frame} marker {names[marker]}: coordinates {points[frame, marker].tolist()} "
                         f"are not finite numbers though the sample is marked present ({int(bad.sum())} sample(s) so); "
                         "the file is damaged: copy or export it again")

"""TRC marker files (OpenSim's text format): the text of labelled points, reading back what that wrote, reading any
recording's trajectories.

:func:`trc_text` writes millimetres with the up axis in an ``UpAxis`` column after the eight standard header
fields; a missing sample is an empty field.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from mocapflow.pipeline.errors import InputError


def trc_text(xyz: np.ndarray, names: list[str], fps: float, frames: np.ndarray, up: str, file_name: str) -> str:
    """A TRC file's text: ``xyz`` (frame, marker, 3) mm in the file's axes (NaN: missing), the markers' ``names``,
    the rate, the frame numbers (0-based; written 1-based with their times), the up axis' letter and the file's
    name (its first line)."""
    n_frames = xyz.shape[0]
    lines = [f"PathFileType\t4\t(X/Y/Z)\t{file_name}",
             "DataRate\tCameraRate\tNumFrames\tNumMarkers\tUnits\tOrigDataRate\tOrigDataStartFrame\tOrigNumFrames\tUpAxis",
             f"{fps:.2f}\t{fps:.2f}\t{n_frames}\t{len(names)}\tmm\t{fps:.2f}\t1\t{n_frames}\t{up.upper()}",
             "Frame#\tTime\t" + "\t".join(f"{n}\t\t" for n in names).rstrip("\t"),
             "\t\t" + "\t".join(f"X{i}\tY{i}\tZ{i}" for i in range(1, len(names) + 1))]
    for i in range(n_frames):
        values = "\t".join("" if np.isnan(v) else f"{v:.3f}" for v in xyz[i].ravel())
        lines.append(f"{int(frames[i]) + 1}\t{frames[i] / fps:.5f}\t{values}")
    return "\n".join(lines) + "\n"


def read_trc(path: Path) -> tuple[np.ndarray, list[str], float]:
    """xyz (frame, marker, 3) mm in the file's axes, labels and rate of a TRC file written by :func:`trc_text`."""
    rows = path.read_text().splitlines()
    header = dict(zip(rows[1].split("\t"), rows[2].split("\t")))
    names = [n for n in rows[3].split("\t")[2:] if n]
    data = [[float(v) if v else np.nan for v in row.split("\t")[2:]] for row in rows[5:] if row.strip()]
    return np.array(data).reshape(len(data), len(names), 3), names, float(header["DataRate"])


def read_trajectories(path: Path) -> tuple[np.ndarray, float, list[str], str]:
    """Any TRC file's trajectories as recorded: points (frame, marker, 3) in the file's unit and axes, NaN where a
    cell is empty, its rate (``DataRate``), its labels and its unit (``Units``)."""
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
    _check_frame_count(path, header, len(rows))
    points = np.full((len(rows), len(names), 3), np.nan)
    for f, row in enumerate(rows):
        for k, cell in enumerate(row[2:2 + 3 * len(names)]):
            if cell.strip():
                points[f, k // 3, k % 3] = _number(path, cell, f, names[k // 3])
    return points, fps, names, unit


def _number(path: Path, cell: str, frame: int, marker: str) -> float:
    """A coordinate cell's value; not a number, or not a finite one (inf, nan, 1e999), is refused."""
    where = f"{path}: line {frame + 6} (frame {frame}) marker {marker}"
    try:
        value = float(cell)
    except ValueError as exc:
        raise InputError(f"{where}: {cell!r} is not a number") from exc
    if not np.isfinite(value):
        raise InputError(f"{where}: {cell.strip()!r} is not a finite number; leave the cell empty for a missing "
                         "sample")
    return value


def _check_frame_count(path: Path, header: dict, n_rows: int) -> None:
    """Refuse a file with fewer data rows than its header's NumFrames (cut short)."""
    try:
        announced = int(header.get("NumFrames", ""))
    except ValueError:
        return  # no frame count to hold it to
    if n_rows < announced:
        raise InputError(f"{path}: holds {n_rows} of the {announced} frames its header's NumFrames announces (the "
                         "file is cut short or damaged); copy or export it again")

"""C3D marker files (through ezc3d): writing labelled points as float data, reading them back, reading any
recording's trajectories.

The writer follows the C3D spec where ezc3d does not: POINT:SCALE is negative (floats) and of magnitude
max |coordinate| / 32000 or the largest residual / 255, whichever is larger (:func:`c3d_scale`), the header's scale
equals it, and each point's word 4 holds the camera bits in its high byte and the residual / |SCALE| in its low
byte (-1 when the point is missing).
"""

from __future__ import annotations

import struct
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
        data = path.read_bytes()
    except OSError as exc:
        raise InputError(f"cannot read {path}: {exc.strerror}; give the path of a C3D file") from exc
    check_layout(path, data)
    try:
        c3d = ezc3d.c3d(str(path))
    except (RuntimeError, ValueError, OSError, IndexError, UnicodeDecodeError, OverflowError) as exc:
        raise InputError(f"{path}: not a readable C3D file ({type(exc).__name__}: {exc}); copy or export it "
                         "again") from exc
    try:
        point = c3d["parameters"]["POINT"]
        points = np.asarray(c3d["data"]["points"][:3], np.float64).transpose(2, 1, 0)  # (frame, marker, 3)
        residuals = np.asarray(c3d["data"]["meta_points"]["residuals"][0]).T  # (frame, marker)
        labels = point["LABELS"]["value"] if point.get("LABELS") else []
        units = point["UNITS"]["value"] if point.get("UNITS") else ["mm"]
        rate = float(c3d["header"]["points"]["frame_rate"])
    except (KeyError, IndexError, TypeError, ValueError, UnicodeDecodeError) as exc:
        raise InputError(f"{path}: the C3D file's POINT parameters or data are incomplete ({type(exc).__name__}: "
                         f"{exc}); copy or export it again") from exc
    present = residuals >= 0
    points[~present] = np.nan
    names = [str(n).strip() for n in labels][:points.shape[1]]
    names += [f"unlabelled{i}" for i in range(len(names), points.shape[1])]
    _check_frame_count(path, points.shape[0])
    _check_finite(path, points, present, names)
    unit = str(units[0]).strip().lower() if len(units) else "mm"
    return points, rate, names, unit


C3D_KEY = 0x50  # a C3D file's second byte, and the parameter section's
PROCESSORS = {84: "<", 85: "<", 86: ">"}  # Intel, DEC (little-endian words), MIPS (big-endian)
PARAMETER_TYPES = (-1, 1, 2, 4)
COUNTS = {("POINT", "USED"): 32767, ("ANALOG", "USED"): 32767, ("FORCE_PLATFORM", "USED"): 64}  # of a C3D's int16  # char, byte, int16, float: the element size is the absolute value


def check_layout(path: Path, data: bytes) -> None:
    """Refuse, before ezc3d reads it, a C3D file whose header or parameter section does not fit its bytes: not a
    C3D file, a parameter section past the end, a parameter claiming more values than its section holds, records
    that do not move forward, a data section claiming more frames than the file holds (cut short). What a header
    claims is checked against the file's size here, before anything of that size is allocated."""
    def refuse(what: str, fix: str = "the file is damaged or not a C3D file: copy or export it again"):
        raise InputError(f"{path}: {what}; {fix}" if what.startswith("holds") else
                         f"{path}: not a readable C3D file: {what}; {fix}")

    if len(data) < 512:
        refuse(f"{len(data)} bytes, shorter than a C3D header (512 bytes)")
    if data[1] != C3D_KEY:
        refuse(f"byte 2 is {data[1]:#04x}, a C3D file's is {C3D_KEY:#04x}")
    block = data[0]
    start = (block - 1) * 512
    if block < 2 or start + 512 > len(data):
        refuse(f"the header puts the parameter section at block {block}, outside the file's "
               f"{len(data) // 512} blocks")
    processor = data[start + 3]
    if processor not in PROCESSORS:
        refuse(f"the parameter section's processor type is {processor}, not 84 (Intel), 85 (DEC) or 86 (MIPS)")
    order = PROCESSORS[processor]
    end = start + data[start + 2] * 512
    if end <= start or end > len(data):
        refuse(f"the parameter section claims {data[start + 2]} blocks from block {block}, but the file has "
               f"{len(data) // 512}")
    params = _parameters(data, start + 4, end, order, refuse)
    words = struct.unpack(order + "5H", data[2:12])
    n_points, n_analog, first, last = words[0], words[1], words[2], words[3]
    (scale,) = struct.unpack(order + "f", data[12:16]) if processor != 85 else (-1.0,)
    (data_block,) = struct.unpack(order + "H", data[16:18])
    offset = (data_block - 1) * 512
    if data_block < 2 or offset > len(data):
        refuse(f"the header puts the data at block {data_block}, outside the file's {len(data) // 512} blocks")
    for key in COUNTS:
        kind, value = params.get(key, (2, 0))
        if kind not in (1, 2) or not 0 <= value <= COUNTS[key]:
            refuse(f"parameter {':'.join(key)} is {value if kind in (1, 2) else 'not an integer'}, not a count from 0 "
                   f"to {COUNTS[key]}")
    n_points = max(n_points, params.get(("POINT", "USED"), (2, 0))[1])
    frames = last - first + 1
    bytes_per_frame = (4 * n_points + n_analog) * (4 if scale < 0 else 2)
    if frames > 0 and bytes_per_frame > 0 and offset + frames * bytes_per_frame > len(data):
        held = max(len(data) - offset, 0) // bytes_per_frame
        refuse(f"holds {held} of the {frames} frames its header announces ({n_points} points and {n_analog} analog "
               f"samples a frame, {frames * bytes_per_frame} bytes from byte {offset}; the file has {len(data)})",
               "the file is cut short or damaged: copy or export it again")


def _parameters(data: bytes, pos: int, end: int, order: str, refuse) -> dict:
    """The first values of the integer parameters (POINT:USED ...), each record checked to lie within the section
    [pos, end), before the next record (its name, dimensions, values and description), and to point forward."""
    groups: dict[int, str] = {}
    found: list[tuple[int, str, int, int]] = []  # (group id, name, type, first value)
    while pos + 2 <= end:
        length, group = struct.unpack("bb", data[pos:pos + 2])
        if length == 0:
            break
        name_end = pos + 2 + abs(length)
        if name_end + 2 > end:
            refuse(f"a parameter record at byte {pos} runs past the parameter section (byte {end})")
        name = data[pos + 2:name_end].decode("ascii", "replace").upper()
        (step,) = struct.unpack(order + "h", data[name_end:name_end + 2])
        if step != 0 and name_end + step <= pos + 2:
            refuse(f"the parameter record {name!r} at byte {pos} points back to byte {name_end + step}, not on to "
                   "the next record")
        stop = min(end, name_end + step) if step > 0 else end  # the record's own bytes
        body = name_end + 2
        if group > 0:
            if body + 2 > stop:
                refuse(f"parameter {name!r} at byte {pos} runs past its record (byte {stop})")
            kind, n_dims = struct.unpack("bB", data[body:body + 2])
            if kind not in PARAMETER_TYPES:
                refuse(f"parameter {name!r} at byte {pos} has type {kind}, not one of {list(PARAMETER_TYPES)}")
            if body + 2 + n_dims > stop:
                refuse(f"parameter {name!r} at byte {pos} has {n_dims} dimensions, more than its record holds (it "
                       f"ends at byte {stop})")
            dims = [int(d) for d in data[body + 2:body + 2 + n_dims]]
            size = abs(kind)
            for d in dims:
                size *= d
            body += 2 + n_dims
            if body + size > stop:
                refuse(f"parameter {name!r} at byte {pos} claims dimensions {dims[:8]}{'...' if n_dims > 8 else ''} "
                       f"({size} bytes), more than its record holds (it ends at byte {stop})")
            if kind in (1, 2) and size >= kind:
                value = struct.unpack(order + ("h" if kind == 2 else "B"), data[body:body + kind])[0]
                found.append((group, name, kind, value))
            else:
                found.append((group, name, kind, -1))
            body += size
        elif group < 0:
            groups[-group] = name
        if body + 1 > stop or body + 1 + data[body] > stop:
            refuse(f"the description of {name!r} at byte {pos} runs past its record (byte {stop})")
        if step == 0:
            break
        pos = name_end + step
    return {(groups.get(g, "?"), name): (kind, value) for g, name, kind, value in found}


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

"""The DeepMoCap dataset's own files as a dataset kind (``kind: dmc``), read into the raw-sequence schema.

Layout of one recording (a sequence) inside the dataset's ``path``::

    take1/
      D4.extrinsics                       the sensor's pose (or D4/D4.extrinsics)
      D4/<prefix>05433depth.pgm           depth, 16-bit binary PGM (P5, big-endian), millimetres, 0 = none
      D4/<prefix>05433mc_blob.png         the colorized depth (JET), the reflectors' pixels black
      D4/<prefix>05433flow.png            the colorized 3D optical flow (optional, checked, not read)
      D4/<prefix>05433ir.pgm              the IR image, 16-bit PGM (optional)
      D6.extrinsics, D6/ ...

A view is a folder of frames with its ``<view>.extrinsics``; a frame's number is the run of digits right
before its suffix (``depth.pgm``, ``mc_blob.png``, ``flow.png``, ``ir.pgm``), whatever comes before it (the
dataset writes ``<take>_<view>_<number>``). Numbers are consecutive and the same for every file kind and every
view; flow may lack the first frame (it is the motion from the previous one).

Conventions of the files, and what the reader does with them:

* **Extrinsics.** Four lines of three numbers: a 3x3 rotation ``R`` (one row per line), then the sensor's
  position ``t`` in millimetres, so that a point of the sensor's camera space maps to the world as
  ``X_world = R @ X_cam + t`` (DeepMoCap's testing code applies it so). The world is Z up (``up: y`` turns a
  Y-up world onto Z up). The files print three decimals, so ``R`` is orthonormal only to about 1e-3: a matrix
  within ``ORTHONORMAL_TOL`` of a rotation is replaced by the nearest one (SVD), anything else is refused.
* **Camera axes.** The sensor's camera space is the Kinect's: x to the sensor's left, y up, z forward (the
  columns of ``R``). The project's cameras are OpenCV's (x right, y down, z forward), the same axes turned half
  a turn about z: ``R_cv = R @ diag(-1, -1, 1)``, still a proper rotation. A file whose camera y axis points
  down in the world is refused (its axes are likely OpenCV's already: set ``camera_axes: opencv``).
* **Mirroring.** The Kinect delivers its images mirrored: a pixel's column grows towards the sensor's left,
  the way its camera x does, so the images are mirror images of what a camera with those extrinsics would
  see. With ``mirrored: true`` (the default) every image is flipped left to right on reading, and the
  intrinsics, given in the files' (mirrored) pixel coordinates as the Kinect SDK reports them, follow the
  flip: ``cx -> width - 1 - cx`` and the tangential ``p2 -> -p2`` (x -> -x in the distortion model).
* **Intrinsics.** The files hold none (DeepMoCap ships per-pixel ray tables, ``.pmm``, which are not read),
  so the catalog gives them: ``intrinsics: {fx, fy, cx, cy, dist: [k1, k2, p1, p2, k3]}`` for every view, or
  ``intrinsics: {D4: {...}, D6: {...}}`` per view (``dist`` optional, zeros).
* **Reflectors.** Without an IR image, the reflector mask is the colorized depth's black pixels (every
  channel at most ``BLACK_MAX``; JET has no black, so only the subtracted mask is), and the raw sequence gets
  a stand-in IR: ``STANDIN_REFLECTOR_IR`` on the mask (above the ``masks`` stage's threshold), the
  colorized depth's grey level times ``STANDIN_GREY_GAIN`` elsewhere (below it). A colorization that blacks out
  invalid depth as well would turn it into reflectors, so a first frame with more than ``MAX_BLACK_FRACTION``
  of its pixels black is refused.
"""

from __future__ import annotations

import re
import struct
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping

import numpy as np
import xarray as xr

from mocapflow.pipeline.errors import CatalogError, InputError
from mocapflow.pipeline.hashing import digest
from mocapflow.schemas.raw import make_raw_sequence
from mocapflow.tasks.shared.cameras import CalibrationError, calibrated_camera, reframed
from mocapflow.tasks.shared.kinematics import Y_UP_TO_Z_UP

SUFFIXES = {"depth": "depth.pgm", "colour": "mc_blob.png", "flow": "flow.png", "ir": "ir.pgm"}
REQUIRED = ("depth", "colour")
KINECT_TO_OPENCV = np.diag([-1.0, -1.0, 1.0])  # x left, y up -> x right, y down (z forward in both)
ORTHONORMAL_TOL = 1e-2  # three printed decimals leave ~1e-3
BLACK_MAX = 16  # a channel at most this is black (JET's darkest colour has a channel at 128)
MAX_BLACK_FRACTION = 0.05  # reflectors cover well under 1% of a frame
STANDIN_REFLECTOR_IR = 64000
STANDIN_GREY_GAIN = 32  # grey 0..255 -> IR 0..8160, under the masks stage's default threshold of 30000
UNITS_M = {"mm": 0.001, "m": 1.0}
DEFAULT_FPS = 30.0  # the Kinect for Xbox One's frame rate
INTRINSICS_HELP = ("'intrinsics: {fx, fy, cx, cy, dist: [k1, k2, p1, p2, k3]}' (pixels of the files' images, as the "
                   "Kinect SDK reports them) for every view, or one such mapping per view name")


@dataclass(frozen=True)
class Settings:
    """A dmc dataset's options, checked."""

    fps: float
    mirrored: bool
    up: str
    unit: str
    camera_axes: str
    intrinsics: Mapping[str, Any]


def settings(dataset) -> Settings:
    """The checked options of a dmc dataset (CatalogError naming the key, the value and the fix)."""
    opts = dataset.options
    where = dataset.where
    fps = opts.get("fps", DEFAULT_FPS)
    if isinstance(fps, bool) or not isinstance(fps, (int, float)) or not np.isfinite(fps) or fps <= 0:
        raise CatalogError(f"{where}.fps: {fps!r} is not a positive number of frames per second; the DeepMoCap "
                           f"recordings are {DEFAULT_FPS:g}")
    choices = {"mirrored": (True, False), "up": ("z", "y"), "unit": tuple(UNITS_M), "camera_axes": ("kinect", "opencv")}
    defaults = {"mirrored": True, "up": "z", "unit": "mm", "camera_axes": "kinect"}
    picked = {}
    for key, allowed in choices.items():
        value = opts.get(key, defaults[key])
        if value not in allowed or isinstance(value, bool) != isinstance(allowed[0], bool):
            raise CatalogError(f"{where}.{key}: {value!r} is not one of {list(allowed)}")
        picked[key] = value
    intrinsics = opts.get("intrinsics")
    if not isinstance(intrinsics, Mapping) or not intrinsics:
        raise CatalogError(f"{where}: a 'dmc' dataset needs {INTRINSICS_HELP}; the DeepMoCap files hold none")
    return Settings(float(fps), intrinsics=intrinsics, **picked)


def _view_intrinsics(s: Settings, view: str, where: str) -> dict[str, Any]:
    """The files' intrinsics of ``view``: the shared mapping, or the view's own."""
    values = s.intrinsics
    if "fx" not in values:
        if view not in values:
            raise CatalogError(f"{where}.intrinsics: no entry for view {view!r} (views given: {sorted(values)}); "
                               f"add one, or give {INTRINSICS_HELP}")
        values = values[view]
    if not isinstance(values, Mapping):
        raise CatalogError(f"{where}.intrinsics.{view}: must be a mapping; expected {INTRINSICS_HELP}")
    missing = [k for k in ("fx", "fy", "cx", "cy") if k not in values]
    unknown = sorted(set(values) - {"fx", "fy", "cx", "cy", "dist"})
    if missing or unknown:
        raise CatalogError(f"{where}.intrinsics (view {view!r}): {'missing ' + str(missing) if missing else ''}"
                           f"{' unknown ' + str(unknown) if unknown else ''}; expected {INTRINSICS_HELP}")
    return {"fx": values["fx"], "fy": values["fy"], "cx": values["cx"], "cy": values["cy"],
            "dist": values.get("dist", [0.0] * 5)}


# ---- the sensor's pose ---------------------------------------------------------------------------
def read_extrinsics(path: Path, *, unit: str = "mm", up: str = "z", camera_axes: str = "kinect") -> np.ndarray:
    """The 4x4 camera-to-world pose of a DeepMoCap ``.extrinsics`` file, for an OpenCV camera (x right, y down,
    z forward), in metres, world Z up. See the module docstring for the file's conventions."""
    try:
        text = path.read_text(encoding="utf-8", errors="replace")
    except OSError as exc:
        raise InputError(f"cannot read {path}: {exc.strerror}") from exc
    rows = [line.split() for line in text.splitlines() if line.strip()]
    try:
        values = np.array(rows, dtype=np.float64)
    except ValueError as exc:
        raise InputError(f"{path}: expected 4 lines of 3 numbers (rotation rows, then the position in {unit}), got "
                         f"{[' '.join(r) for r in rows]}; export the sensor's extrinsics again") from exc
    if values.shape != (4, 3) or not np.isfinite(values).all():
        raise InputError(f"{path}: expected 4 lines of 3 finite numbers (rotation rows, then the position in {unit}), "
                         f"got {values.tolist()}; export the sensor's extrinsics again")
    rot, position = values[:3], values[3] * UNITS_M[unit]
    if np.linalg.det(rot) <= 0 or np.abs(rot @ rot.T - np.eye(3)).max() > ORTHONORMAL_TOL:
        raise InputError(f"{path}: the first three lines {rot.tolist()} are not a rotation (orthonormal to "
                         f"{ORTHONORMAL_TOL}, determinant +1); the file is damaged or not a DeepMoCap extrinsics file")
    u, _, vt = np.linalg.svd(rot)
    rot = u @ vt  # the nearest rotation to the printed one
    world = Y_UP_TO_Z_UP if up == "y" else np.eye(3)
    camera_up = (world @ rot)[2, 1]  # world z of the camera's y axis
    if camera_axes == "kinect":
        if camera_up < 0:
            raise InputError(f"{path}: the camera's y axis points down in the world (z component {camera_up:.3f}); "
                             "DeepMoCap's camera axes are x left, y up: these look like OpenCV's (y down), so set "
                             "'camera_axes: opencv' in the dataset (or 'up' if the world is not Z up)")
        rot = rot @ KINECT_TO_OPENCV
    pose = np.eye(4)
    pose[:3, :3], pose[:3, 3] = rot, position
    return reframed(pose, world)


def mirrored_intrinsics(values: Mapping[str, Any], width: int) -> dict[str, Any]:
    """Intrinsics of a mirrored image flipped back: the principal point's column and the sign of p2."""
    dist = [float(d) for d in values["dist"]]
    if len(dist) == 5:
        dist[3] = -dist[3]
    return {**values, "cx": width - 1 - float(values["cx"]), "dist": dist}


# ---- files ----------------------------------------------------------------------------------------
def _frame_files(folder: Path) -> dict[str, dict[int, Path]]:
    """The numbered files of a view's folder, by kind and number."""
    out: dict[str, dict[int, Path]] = {kind: {} for kind in SUFFIXES}
    for path in sorted(folder.iterdir()):
        for kind, suffix in SUFFIXES.items():
            if path.name.lower().endswith(suffix.lower()):
                match = re.search(r"([0-9]+)$", path.name[:-len(suffix)])
                if match is None:
                    raise InputError(f"{path}: a frame's name must end in its number before '{suffix}' (e.g. "
                                     f"take_D4_05433{suffix}); rename it")
                number = int(match.group(1))
                if number in out[kind]:
                    raise InputError(f"{out[kind][number]} and {path} have the same frame number {number}; keep one")
                out[kind][number] = path
    return out


def _check_numbers(folder: Path, files: dict[str, dict[int, Path]]) -> list[int]:
    """The view's frame numbers: consecutive depth frames, the same for the colorized depth and the IR, the same
    or all but the first for the flow."""
    for kind in REQUIRED:
        if not files[kind]:
            raise InputError(f"{folder}: has no *{SUFFIXES[kind]} files; every DeepMoCap view needs its depth "
                             f"(<number>{SUFFIXES['depth']}) and colorized depth (<number>{SUFFIXES['colour']})")
    numbers = sorted(files["depth"])
    gaps = [(a, b) for a, b in zip(numbers, numbers[1:]) if b != a + 1]
    if gaps:
        a, b = gaps[0]
        raise InputError(f"{folder}: depth frame {a + 1} is missing (frames jump from {a} to {b}); frames must be "
                         "numbered consecutively: restore the frame or cut the take at the gap")
    for kind in ("colour", "ir", "flow"):
        got = sorted(files[kind])
        if kind in ("ir", "flow") and not got:
            continue
        if got == numbers or (kind == "flow" and got == numbers[1:]):
            continue
        extra, lacking = sorted(set(got) - set(numbers)), sorted(set(numbers) - set(got))
        raise InputError(f"{folder}: {len(numbers)} depth frames ({_span(numbers)}) but {len(got)} *{SUFFIXES[kind]} "
                         f"frames ({_span(got)}; missing {lacking[:5]}, extra {extra[:5]}); every frame needs one "
                         "file of each kind with the same number")
    return numbers


def _span(numbers: list[int]) -> str:
    return f"{numbers[0]}-{numbers[-1]}" if numbers else "none"


_PGM_HEADER = re.compile(rb"P5\s+(?:#[^\n]*\n\s*)*(\d+)\s+(?:#[^\n]*\n\s*)*(\d+)\s+(?:#[^\n]*\n\s*)*(\d+)\s")


def pgm_header(path: Path) -> tuple[int, int, int]:
    """(width, height, header length) of a 16-bit binary PGM; anything else refused naming what it is."""
    try:
        with open(path, "rb") as fh:
            head = fh.read(512)
    except OSError as exc:
        raise InputError(f"cannot read {path}: {exc.strerror}") from exc
    match = _PGM_HEADER.match(head)
    if match is None:
        kind = f"an ASCII PGM ({head[:2]!r})" if head[:2] == b"P2" else f"not a binary PGM (starts {head[:8]!r})"
        raise InputError(f"{path} is {kind}; depth frames must be binary 16-bit PGMs (P5, maxval above 255) in mm")
    width, height, maxval = (int(g) for g in match.groups())
    if maxval < 256:
        raise InputError(f"{path} is an 8-bit PGM (maxval {maxval}); depth frames must be 16-bit PGMs in millimetres "
                         "(maxval above 255): export the raw depth, not a scaled preview")
    if maxval > 65535:
        raise InputError(f"{path}: maxval {maxval} is above 65535; not a valid PGM")
    return width, height, match.end()


def read_pgm(path: Path, size: tuple[int, int]) -> np.ndarray:
    """A 16-bit PGM's pixels (big-endian, as the format says), checked against ``size`` (width, height)."""
    width, height, start = pgm_header(path)
    if (width, height) != size:
        raise InputError(f"{path} is {width}x{height} px but the view's first depth frame is {size[0]}x{size[1]}; "
                         "every frame of a view has one size")
    data = path.read_bytes()[start:start + 2 * width * height]
    if len(data) != 2 * width * height:
        raise InputError(f"{path} is truncated: {len(data)} of {2 * width * height} pixel bytes; copy the file again")
    return np.frombuffer(data, dtype=">u2").reshape(height, width).astype(np.uint16)


def _png_size(path: Path) -> tuple[int, int, int, int]:
    """(width, height, bit depth, colour type) of a PNG's header."""
    try:
        with open(path, "rb") as fh:
            head = fh.read(26)
    except OSError as exc:
        raise InputError(f"cannot read {path}: {exc.strerror}") from exc
    if len(head) < 26 or head[:8] != b"\x89PNG\r\n\x1a\n" or head[12:16] != b"IHDR":
        raise InputError(f"{path} is not a PNG file; the colorized depth and flow are 8-bit colour PNGs")
    return (*struct.unpack(">II", head[16:24]), head[24], head[25])


def _check_png(path: Path, size: tuple[int, int]) -> None:
    width, height, bits, colour = _png_size(path)
    if bits != 8 or colour not in (2, 6):
        raise InputError(f"{path} is a {bits}-bit PNG of colour type {colour}; the colorized images are 8-bit RGB "
                         "(colour type 2, or 6 with alpha)")
    if (width, height) != size:
        raise InputError(f"{path} is {width}x{height} px but the view's depth frames are {size[0]}x{size[1]}; "
                         "the colorized depth and flow have the depth's size")


def read_colour(path: Path) -> np.ndarray:
    """An 8-bit colour PNG as (y, x, 3) BGR."""
    import cv2

    img = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if img is None:
        raise InputError(f"{path}: cannot decode the PNG; copy the file again")
    return img


def black_mask(colour: np.ndarray) -> np.ndarray:
    """The reflector mask of a colorized depth: its black pixels (every channel at most ``BLACK_MAX``).
    (y, x, 3) uint8 -> (y, x) bool"""
    return (colour <= BLACK_MAX).all(axis=-1)  # Eq. I_CD = JET(D) - I_IRm, DeepMoCap §3.2


def standin_ir(colour: np.ndarray) -> np.ndarray:
    """A stand-in IR image: reflectors bright, elsewhere the colorized depth's grey level, dim.
    (y, x, 3) uint8 BGR -> (y, x) uint16"""
    import cv2

    grey = cv2.cvtColor(colour, cv2.COLOR_BGR2GRAY).astype(np.uint16) * STANDIN_GREY_GAIN
    return np.where(black_mask(colour), np.uint16(STANDIN_REFLECTOR_IR), grey).astype(np.uint16)


# ---- discovery and reading -----------------------------------------------------------------------
def _views(seq_dir: Path) -> dict[str, tuple[Path, Path]]:
    """{view: (image folder, extrinsics file)} of a sequence folder, each view with both."""
    beside = {p.name[:-len(".extrinsics")]: p for p in seq_dir.glob("*.extrinsics") if p.is_file()}
    folders = {p.name: p for p in seq_dir.iterdir() if p.is_dir()
               and (any(p.glob(f"*{SUFFIXES['depth']}")) or (p / f"{p.name}.extrinsics").is_file())}
    out = {}
    for view in sorted(set(beside) | set(folders)):
        folder = seq_dir / view
        inside = folder / f"{view}.extrinsics"
        if view not in folders:
            raise InputError(f"{beside[view]}: view {view!r} has no image folder {folder}; put its numbered "
                             f"*{SUFFIXES['depth']} and *{SUFFIXES['colour']} files there, or remove the extrinsics")
        if inside.is_file() and view in beside:
            raise InputError(f"{seq_dir}: view {view!r} has two extrinsics files, {beside[view]} and {inside}; "
                             "keep one")
        extrinsics = inside if inside.is_file() else beside.get(view)
        if extrinsics is None:
            raise InputError(f"{folder}: view {view!r} has no extrinsics; expected {seq_dir / (view + '.extrinsics')} "
                             f"or {inside} (4 lines: the rotation's rows, then the position in mm)")
        out[view] = (folder, extrinsics)
    return out


def is_sequence(folder: Path) -> bool:
    """A folder holding DeepMoCap views (an extrinsics file beside or inside a view folder)."""
    return folder.is_dir() and (any(folder.glob("*.extrinsics")) or any(folder.glob("*/*.extrinsics")))


def describe(dataset, seq_dir: Path) -> tuple[dict, int, str]:
    """A sequence folder checked at the door: the per-view calibration (OpenCV, after the mirroring), the frame
    count and the fingerprint of its files. Reads headers and each view's first colorized depth only."""
    s = settings(dataset)
    views = _views(seq_dir)
    if not views:
        raise InputError(f"{seq_dir}: no DeepMoCap views (a folder of frames with its <view>.extrinsics)")
    cameras, counts, listing = {}, {}, []
    for view, (folder, ext_path) in views.items():
        files = _frame_files(folder)
        numbers = _check_numbers(folder, files)
        width, height, _ = pgm_header(files["depth"][numbers[0]])
        for path in files["depth"].values():
            if pgm_header(path)[:2] != (width, height):
                raise InputError(f"{path} is {pgm_header(path)[0]}x{pgm_header(path)[1]} px but "
                                 f"{files['depth'][numbers[0]]} is {width}x{height}; every frame of a view has one size")
        for kind in ("colour", "flow"):
            for path in files[kind].values():
                _check_png(path, (width, height))
        for path in files["ir"].values():
            if pgm_header(path)[:2] != (width, height):
                raise InputError(f"{path}: the IR frame's size differs from the depth's {width}x{height}")
        if not files["ir"]:
            _check_black(files["colour"][numbers[0]])
        intr = _view_intrinsics(s, view, dataset.where)
        if s.mirrored:
            intr = mirrored_intrinsics(intr, width)
        pose = read_extrinsics(ext_path, unit=s.unit, up=s.up, camera_axes=s.camera_axes)
        try:
            cam = calibrated_camera(view, **intr, cam_to_world=pose, width=width, height=height)
        except CalibrationError as exc:
            raise CatalogError(f"{dataset.where}.intrinsics: {exc}; expected {INTRINSICS_HELP}") from exc
        cameras[view] = {**cam.as_dict(), "files": {k: [str(files[k][n]) for n in numbers if n in files[k]]
                                                    for k in ("depth", "colour", "ir")}}
        counts[view] = len(numbers)
        listing += sorted((p.relative_to(seq_dir).as_posix(), p.stat().st_size, p.stat().st_mtime_ns)
                          for p in [ext_path, *(q for kind in files.values() for q in kind.values())])
    if len(set(counts.values())) != 1:
        raise InputError(f"{seq_dir}: views have different numbers of frames {counts}; every view needs the same frames")
    return cameras, next(iter(counts.values())), digest([listing, dataset.options])


def _check_black(path: Path) -> None:
    colour = read_colour(path)
    fraction = float(black_mask(colour).mean())
    if fraction > MAX_BLACK_FRACTION:
        raise InputError(f"{path}: {fraction:.0%} of the pixels are black, but the reflectors (the black pixels of a "
                         f"DeepMoCap colorized depth) cover far less than {MAX_BLACK_FRACTION:.0%}; this colorization "
                         "blacks out more than the reflectors (invalid depth?): give the IR frames (<number>ir.pgm) "
                         "or re-colorize with only the reflector mask black")


def read(seq_views: Mapping[str, Mapping], mirrored: bool, fps: float, start: int, stop: int) -> xr.Dataset:
    """Frames [start, stop) of a described sequence (``describe``'s per-view calibration with its files)."""
    depth, ir = [], []
    for cam in seq_views.values():
        size = (int(cam["width"]), int(cam["height"]))
        files = cam["files"]
        d = np.stack([read_pgm(Path(p), size) for p in files["depth"][start:stop]])
        if files["ir"]:
            i = np.stack([read_pgm(Path(p), size) for p in files["ir"][start:stop]])
        else:
            i = np.stack([standin_ir(read_colour(Path(p))) for p in files["colour"][start:stop]])
        if mirrored:
            d, i = d[:, :, ::-1], i[:, :, ::-1]
        depth.append(d)
        ir.append(i)
    calib = {view: {k: v for k, v in cam.items() if k != "files"} for view, cam in seq_views.items()}
    return make_raw_sequence(np.stack(depth), np.stack(ir), calib, fps, start)

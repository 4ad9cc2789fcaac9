"""The DeepMoCap system's dataset kinds: raw IR + depth sequences in the raw-sequence schema.

  zarr    a folder of raw-sequence zarr stores (one per sequence, ``<id>.zarr``)
  images  a folder of sequences as 16-bit PNGs: ``<id>/calibration.yaml`` and ``<id>/<view>/{depth,ir}/<frame:06d>.png``
  dmc     the DeepMoCap dataset's own files: per view numbered depth PGMs, colorized depth PNGs (reflectors
          black), optional IR and flow, and the sensor's ``.extrinsics`` (systems/deepmocap/dmc_files.py: the
          mirrored images and the Kinect's x-left, y-up camera axes)

Only these readers touch those raw-input files.
"""

from __future__ import annotations

import re
import struct
from pathlib import Path
from typing import Mapping

import cv2
import numpy as np
import xarray as xr
import yaml

from mocapflow.pipeline.datasets import (CALIBRATION_HELP, SequenceInfo, check_fps, check_names, checked_camera,
                                         data_folder, data_pattern)
from mocapflow.pipeline.errors import CatalogError, InputError
from mocapflow.pipeline.hashing import digest
from mocapflow.pipeline.storage import check
from mocapflow.schemas import get_schema
from mocapflow.schemas.raw import make_raw_sequence
from mocapflow.systems.deepmocap import dmc_files

# ---- zarr ---------------------------------------------------------------------------------
class ZarrReader:
    options = ("path", "pattern")

    @staticmethod
    def discover(catalog, dataset) -> list[SequenceInfo]:
        folder = data_folder(catalog, dataset)
        pattern = data_pattern(dataset, "*.zarr")
        out = []
        for store in sorted(folder.glob(pattern)):
            ds = _open_raw(store)
            check_names(dataset.where, store.name.removesuffix(".zarr"), [str(v) for v in ds["view"].values],
                        f" ({store})")
            check_raw_header(ds, store)
            files = sorted((p.relative_to(store).as_posix(), p.stat().st_size, p.stat().st_mtime_ns)
                           for p in store.rglob("*") if p.is_file())
            out.append(SequenceInfo(store.name.removesuffix(".zarr"), tuple(str(v) for v in ds["view"].values),
                                    ds.sizes["frame"], digest(files), {"path": str(store)},
                                    image=(ds.sizes["y"], ds.sizes["x"])))
        if not out:
            raise InputError(f"{dataset.where}: no raw-sequence stores match {pattern!r} in {folder}")
        return out

    @staticmethod
    def read(dataset, seq: SequenceInfo, start: int, stop: int) -> xr.Dataset:
        ds = _open_raw(Path(seq.spec["path"]))
        return ds.isel(frame=slice(start, stop)).load()


def _open_raw(store: Path) -> xr.Dataset:
    try:
        ds = xr.open_zarr(store, consolidated=False, chunks=None)
    except (OSError, ValueError, KeyError) as exc:
        raise InputError(f"{store} is not a readable zarr raw sequence ({exc}); "
                         "write it with mocapflow synth or in the raw-sequence schema") from exc
    check(get_schema("raw_sequence"), ds, f"raw sequence {store}")
    return ds


def check_raw_header(ds: xr.Dataset, store: Path) -> None:
    """A raw-sequence store's fps, timestamps and calibration (finite, image size as its arrays'), read without
    reading its frames."""
    fps = ds.attrs.get("fps")
    check_fps(fps, f"{store}: attribute 'fps'")
    stamps = np.asarray(ds["timestamp"].values, dtype=np.float64)
    bad = np.flatnonzero(~np.isfinite(stamps))
    if bad.size:
        raise InputError(f"{store}: timestamp of frame {int(bad[0])} is {stamps[bad[0]]}; every frame needs a finite "
                         "time in seconds")
    back = np.flatnonzero(np.diff(stamps) <= 0)
    if back.size:
        f = int(back[0]) + 1
        raise InputError(f"{store}: timestamps must increase strictly, but frame {f} is at {stamps[f]} s after frame "
                         f"{f - 1} at {stamps[f - 1]} s; fix the recording's timestamps")
    calib = ds[["fx", "fy", "cx", "cy", "dist", "cam_to_world", "width", "height"]].load()
    for view in ds["view"].values:
        cam = checked_camera(str(view), {k: calib[k].sel(view=view).values for k in calib.data_vars}, f"{store}")
        if (cam.width, cam.height) != (ds.sizes["x"], ds.sizes["y"]):
            raise InputError(f"{store}: view {str(view)!r} is calibrated for {cam.width}x{cam.height} px but its images "
                             f"are {ds.sizes['x']}x{ds.sizes['y']}; fix 'width'/'height' or the images")


# ---- images -------------------------------------------------------------------------------
PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
_FRAME_NAME = re.compile(r"([0-9]+)\.png")


class ImageFolderReader:
    """``<id>/calibration.yaml`` and ``<id>/<view>/{depth,ir}/<frame>.png``: 16-bit grayscale PNGs of the size the
    calibration gives, numbered consecutively (``000000.png``, ``000001.png``, ...; any first number, no gap),
    the same numbers for depth and IR and for every view. Frames are ordered by number, never by name."""

    options = ("path", "pattern")

    @staticmethod
    def discover(catalog, dataset) -> list[SequenceInfo]:
        folder = data_folder(catalog, dataset)
        pattern = data_pattern(dataset, "*")
        out = []
        for seq_dir in sorted(p for p in folder.glob(pattern) if (p / "calibration.yaml").is_file()):
            calib = read_calibration_yaml(seq_dir)
            views = tuple(calib["views"])
            check_names(dataset.where, seq_dir.name, views, f" ({seq_dir})")  # before any view's folder is read
            numbers = {v: _view_frames(seq_dir, v, calib["cameras"][v]) for v in views}
            counts = {v: len(n) for v, n in numbers.items()}
            if len({(n[0], len(n)) if n else None for n in numbers.values()}) != 1:
                raise InputError(f"{seq_dir}: views have different frames {_spans(numbers)}; every view needs the "
                                 "same frame numbers")
            files = sorted((p.relative_to(seq_dir).as_posix(), p.stat().st_size, p.stat().st_mtime_ns)
                           for p in seq_dir.rglob("*") if p.is_file())
            sizes = {(calib["cameras"][v].height, calib["cameras"][v].width) for v in views}
            out.append(SequenceInfo(seq_dir.name, views, counts[views[0]] if views else 0, digest(files),
                                    {"path": str(seq_dir)}, image=max(sizes, key=lambda s: s[0] * s[1])))
        if not out:
            raise InputError(f"{dataset.where}: no sequence folders with calibration.yaml in {folder}")
        return out

    @staticmethod
    def read(dataset, seq: SequenceInfo, start: int, stop: int) -> xr.Dataset:
        seq_dir = Path(seq.spec["path"])
        calib = read_calibration_yaml(seq_dir)
        depth, ir = [], []
        for view in seq.views:
            cam = calib["cameras"][view]
            for kind, sink in (("depth", depth), ("ir", ir)):
                files = [path for _, path in _numbered_pngs(seq_dir / view / kind)][start:stop]
                frames = [cv2.imread(str(f), cv2.IMREAD_UNCHANGED) for f in files]
                for f, img in zip(files, frames):
                    if img is None or img.dtype != np.uint16 or img.shape != (cam.height, cam.width):
                        raise InputError(f"{f}: not a readable 16-bit {cam.width}x{cam.height} grayscale PNG (the "
                                         "calibration's size); re-export the frame")
                sink.append(np.stack(frames))
        cameras = {view: cam.as_dict() for view, cam in calib["cameras"].items()}
        return make_raw_sequence(np.stack(depth), np.stack(ir), cameras, calib["fps"], start)


def _numbered_pngs(folder: Path) -> list[tuple[int, Path]]:
    """The PNG frames of ``folder`` as (number, path), by number; a name that is not a number is refused."""
    if not folder.is_dir():
        raise InputError(f"{folder} is missing; each view needs depth/ and ir/ folders of numbered PNGs")
    out = []
    for path in folder.iterdir():
        if path.suffix.lower() != ".png":
            continue
        match = _FRAME_NAME.fullmatch(path.name)
        if match is None:
            raise InputError(f"{path}: a frame's name must be its number, e.g. 000000.png; rename it")
        out.append((int(match.group(1)), path))
    out.sort()
    for (a, pa), (b, pb) in zip(out, out[1:]):
        if a == b:
            raise InputError(f"{pa} and {pb} have the same frame number {a}; keep one")
    return out


def _view_frames(seq_dir: Path, view: str, cam) -> list[int]:
    """The frame numbers of one view, checked: consecutive, the same for depth and IR, every PNG 16-bit grayscale
    of the calibrated size."""
    numbered = {kind: _numbered_pngs(seq_dir / view / kind) for kind in ("depth", "ir")}
    for kind, frames in numbered.items():
        for (a, _), (b, _) in zip(frames, frames[1:]):
            if b != a + 1:
                raise InputError(f"{seq_dir / view / kind}: frame {a + 1:06d}.png is missing (frames jump from {a} to "
                                 f"{b}); frames must be numbered consecutively: renumber them or fill the gap")
        for _, path in frames:
            _check_png(path, cam)
    depth, ir = ([n for n, _ in numbered[k]] for k in ("depth", "ir"))
    if depth != ir:
        raise InputError(f"{seq_dir / view}: {len(depth)} depth frames {_span(depth)} but {len(ir)} IR frames "
                         f"{_span(ir)}; every frame needs both a depth and an IR PNG of the same number")
    return depth


def _check_png(path: Path, cam) -> None:
    """A PNG's header (no pixels read): 16-bit grayscale of the camera's size."""
    try:
        with open(path, "rb") as fh:
            head = fh.read(26)
    except OSError as exc:
        raise InputError(f"cannot read {path}: {exc.strerror}") from exc
    if len(head) < 26 or head[:8] != PNG_SIGNATURE or head[12:16] != b"IHDR":
        raise InputError(f"{path} is not a PNG file; frames must be 16-bit grayscale PNGs")
    width, height, bits, color = *struct.unpack(">II", head[16:24]), head[24], head[25]
    if bits != 16 or color != 0:
        raise InputError(f"{path} is a {bits}-bit {'grayscale' if color == 0 else 'colour'} PNG; frames must be "
                         "16-bit grayscale (depth in mm, IR counts)")
    if (width, height) != (cam.width, cam.height):
        raise InputError(f"{path} is {width}x{height} px but view {cam.name!r} is calibrated for {cam.width}x"
                         f"{cam.height}; fix the calibration's width/height or the image")


def _span(numbers: list[int]) -> str:
    return f"{numbers[0]}-{numbers[-1]}" if numbers else "(none)"


def _spans(numbers: Mapping[str, list[int]]) -> dict[str, str]:
    return {view: _span(n) for view, n in numbers.items()}


class _UniqueKeySafeLoader(yaml.SafeLoader):
    """yaml.safe_load that refuses a mapping naming a key twice (a second view of the same name would replace the
    first)."""


def _unique_mapping(loader: yaml.SafeLoader, node: yaml.MappingNode, deep: bool = False) -> dict:
    seen = set()
    for key_node, _ in node.value:
        key = loader.construct_object(key_node, deep=True)
        if key in seen:
            raise yaml.constructor.ConstructorError(None, None, f"key {key!r} appears twice", key_node.start_mark)
        seen.add(key)
    return loader.construct_mapping(node, deep=deep)


_UniqueKeySafeLoader.add_constructor(yaml.resolver.BaseResolver.DEFAULT_MAPPING_TAG, _unique_mapping)


def read_calibration_yaml(seq_dir: Path) -> dict:
    """calibration.yaml of a sequence folder, checked: ``fps``, and per view a checked Camera (``cameras``)."""
    path = seq_dir / "calibration.yaml"
    try:
        calib = yaml.load(path.read_text(), Loader=_UniqueKeySafeLoader)
    except OSError as exc:
        raise InputError(f"cannot read {path}: {exc.strerror}") from exc
    except yaml.YAMLError as exc:
        raise InputError(f"{path}: not valid YAML ({exc}); expected {CALIBRATION_HELP}") from exc
    if not isinstance(calib, dict) or "fps" not in calib or not isinstance(calib.get("views"), dict) \
            or not calib["views"]:
        raise InputError(f"{path}: expected {CALIBRATION_HELP}")
    fps = check_fps(calib["fps"], f"{path}: fps")
    cameras = {}
    for name, values in calib["views"].items():
        if not isinstance(values, dict):
            raise InputError(f"{path}: views.{name} must be a mapping; expected {CALIBRATION_HELP}")
        cameras[str(name)] = checked_camera(str(name), values, str(path))
    return {"fps": fps, "views": {str(k): v for k, v in calib["views"].items()}, "cameras": cameras}


class DeepMoCapReader:
    """The DeepMoCap dataset's recordings, one sequence per folder (systems/deepmocap/dmc_files.py): ``path`` and
    ``pattern`` as an image dataset's, ``intrinsics`` (the files hold none), ``fps`` (30), ``mirrored`` (true:
    flip the Kinect's mirrored images), ``up`` (z), ``unit`` of the extrinsics' positions (mm) and
    ``camera_axes`` (kinect: x left, y up; or opencv)."""

    options = ("path", "pattern", "intrinsics", "fps", "mirrored", "up", "unit", "camera_axes")

    @staticmethod
    def discover(catalog, dataset) -> list[SequenceInfo]:
        folder = data_folder(catalog, dataset)
        pattern = data_pattern(dataset, "*")
        dmc_files.settings(dataset)  # the options, before any file is read
        if any(folder.glob("*.extrinsics")):
            raise CatalogError(f"{dataset.where}.path: {folder} holds extrinsics files, so it is one take, not a "
                               f"folder of takes; point 'path' at the folder that holds it ({folder.parent})")
        out = []
        for seq_dir in sorted(p for p in folder.glob(pattern) if dmc_files.is_sequence(p)):
            check_names(dataset.where, seq_dir.name, [], f" ({seq_dir})", has_views=False)
            views, n_frames, fingerprint = dmc_files.describe(dataset, seq_dir)
            check_names(dataset.where, seq_dir.name, list(views), f" ({seq_dir})")
            out.append(SequenceInfo(seq_dir.name, tuple(views), n_frames, fingerprint,
                                    {"path": str(seq_dir), "views": views},
                                    image=max(((c["height"], c["width"]) for c in views.values()),
                                              key=lambda size: size[0] * size[1])))
        if not out:
            raise InputError(f"{dataset.where}: no DeepMoCap recordings in {folder} (folders matching {pattern!r} "
                             "with <view>.extrinsics files and <view>/ folders of numbered depth.pgm and mc_blob.png "
                             "files)")
        return out

    @staticmethod
    def read(dataset, seq: SequenceInfo, start: int, stop: int) -> xr.Dataset:
        s = dmc_files.settings(dataset)
        return dmc_files.read(seq.spec["views"], s.mirrored, s.fps, start, stop)

"""Dataset readers: where raw sequences come from, and the `frames` source stage.

Kinds:
  studio  sequences synthesized by the studio (tasks/studio) from per-sequence specs
  zarr    a folder of raw-sequence zarr stores (one per sequence, ``<id>.zarr``)
  images  a folder of sequences as 16-bit PNGs:
          ``<id>/calibration.yaml`` and ``<id>/<view>/{depth,ir}/<frame:06d>.png``
  markers a folder of optical marker recordings, C3D or TRC (``<id>.c3d``), read as raw_markers
  studio_markers  unlabelled marker takes filmed on the studio's mesh body, as raw_markers with ground truth
  studio_suit  checkerboard-suit takes filmed on the mesh body by grey cameras, as suit_images with ground truth
  dmc     the DeepMoCap dataset's own files: per view numbered depth PGMs, colorized depth PNGs (reflectors
          black), optional IR and flow, and the sensor's ``.extrinsics`` (pipeline/dmc_files.py: the mirrored
          images and the Kinect's x-left, y-up camera axes)

Each reader discovers sequences (id, views, frame count, fingerprint of the raw input) on the
driver, and reads a frame region on a worker. Discovery checks the raw input before any stage runs:
names, frame numbering and counts, image sizes, timestamps, fps and calibration, each failure an
error naming the file, the key or the frame and the fix.

Sequence ids and view names become parts of paths (partitions, export files), so both must match
``NAME_RULE``: letters, digits, ``_``, ``-`` and ``.``, not starting with ``.``; a sequence's view
names are distinct, and a sequence has at least one frame. A zarr or image dataset's ``pattern``
matches names inside its ``path`` and may not leave it (no ``..``, not absolute).

Only this module touches raw-input files. A reader's ``options`` names the catalog keys a dataset
of its kind takes besides ``kind``; the catalog refuses any other key when it is loaded.
"""

from __future__ import annotations

import fnmatch
import re
import struct
from dataclasses import dataclass
from pathlib import Path, PurePosixPath
from typing import Any, Mapping

import numpy as np
import xarray as xr
import yaml

from mocapflow.pipeline.errors import CatalogError, InputError
from mocapflow.pipeline.hashing import digest, file_digest
from mocapflow.pipeline.storage import check
from mocapflow.schemas import get_schema
from mocapflow.schemas.raw import make_raw_sequence
from mocapflow.tasks.shared.body import JOINT_NAMES
from mocapflow.tasks.shared.cache import BoundedCache
from mocapflow.tasks.shared.cameras import CalibrationError, calibrated_camera

NAME_RULE = "[A-Za-z0-9_-][A-Za-z0-9_.-]*"  # sequence ids and view names: they become parts of paths
_NAME = re.compile(NAME_RULE)
CALIBRATION_HELP = ("'fps' (frames per second, > 0) and 'views: {name: {fx, fy, cx, cy, dist: [k1, k2, p1, p2, k3], "
                    "cam_to_world: 4x4, width, height}}'")


@dataclass(frozen=True)
class SequenceInfo:
    id: str
    views: tuple[str, ...]
    n_frames: int
    fingerprint: str
    spec: Mapping[str, Any]  # reader-specific (a studio spec, or a resolved path)


def discover(catalog, dataset, pattern: str | None = None) -> list[SequenceInfo]:
    """The sequences of ``dataset`` (optionally filtered by a glob on their ids), their names checked."""
    reader = DATASET_KINDS[dataset.kind]
    found = reader.discover(catalog, dataset)
    if pattern:
        found = [s for s in found if fnmatch.fnmatchcase(s.id, pattern)]
    for seq in found:
        check_sequence(dataset, seq)
    return sorted(found, key=lambda s: s.id)


def check_sequence(dataset, seq: SequenceInfo) -> None:
    """Refuse a sequence whose id or view names break ``NAME_RULE``, whose views repeat, or that has no frame."""
    source = f" ({seq.spec['path']})" if isinstance(seq.spec, Mapping) and "path" in seq.spec else ""
    error = InputError if source else CatalogError
    check_names(dataset.where, seq.id, seq.views, source, getattr(DATASET_KINDS[dataset.kind], "has_views", True))
    if seq.n_frames <= 0:
        raise error(f"{dataset.where}: sequence {seq.id!r}{source} has no frames ({seq.n_frames}); record or render "
                    "at least one frame, or remove the sequence")


def check_names(where: str, seq_id: str, views, source: str = "", has_views: bool = True) -> None:
    """A sequence id and its view names follow ``NAME_RULE`` (they become parts of paths), the views distinct, and
    (``has_views``: the kind films with sensors) at least one. ``source``: the file they come from (then the error
    is an InputError, else a CatalogError)."""
    error = InputError if source else CatalogError
    if not _NAME.fullmatch(seq_id):
        raise error(f"{where}: sequence id {seq_id!r}{source} is not a valid name: ids become file names, so they must "
                    f"match {NAME_RULE} (letters, digits, _ - ., not starting with '.'); rename it")
    where = f"{where}: sequence {seq_id!r}{source}"
    for view in views:
        if not _NAME.fullmatch(view):
            raise error(f"{where}: view name {view!r} is not a valid name: view names become partition names, so "
                        f"they must match {NAME_RULE}; rename the view")
    repeated = sorted({v for v in views if list(views).count(v) > 1})
    if repeated:
        raise error(f"{where}: view name(s) {repeated} appear more than once in {list(views)}; "
                    "give every sensor its own name")
    if has_views and not views:
        raise error(f"{where}: has no views; a sequence needs at least one sensor")


def _pattern(dataset, default: str) -> str:
    """A dataset's ``pattern``: a glob of names inside its folder, never leaving it."""
    pattern = str(dataset.options.get("pattern", default))
    parts = PurePosixPath(pattern.replace("\\", "/")).parts
    if not pattern or PurePosixPath(pattern).is_absolute() or Path(pattern).is_absolute() or ".." in parts \
            or pattern.startswith("~"):
        raise CatalogError(f"{dataset.where}.pattern: {pattern!r} leaves the dataset's folder; a pattern matches names "
                           f"inside 'path' (e.g. {default!r}): drop the '..', or point 'path' at the other folder "
                           "(inside data_roots)")
    return pattern


def read_frames(dataset, seq: SequenceInfo, start: int, stop: int) -> xr.Dataset:
    """Frames [start, stop) of ``seq`` (found by ``discover``) in the raw-sequence schema."""
    return DATASET_KINDS[dataset.kind].read(dataset, seq, start, stop)


# ---- zarr ---------------------------------------------------------------------------------
class ZarrReader:
    options = ("path", "pattern")

    @staticmethod
    def discover(catalog, dataset) -> list[SequenceInfo]:
        folder = _folder(catalog, dataset)
        pattern = _pattern(dataset, "*.zarr")
        out = []
        for store in sorted(folder.glob(pattern)):
            ds = _open_raw(store)
            check_names(dataset.where, store.name.removesuffix(".zarr"), [str(v) for v in ds["view"].values],
                        f" ({store})")
            check_raw_header(ds, store)
            files = sorted((p.relative_to(store).as_posix(), p.stat().st_size, p.stat().st_mtime_ns)
                           for p in store.rglob("*") if p.is_file())
            out.append(SequenceInfo(store.name.removesuffix(".zarr"), tuple(str(v) for v in ds["view"].values),
                                    ds.sizes["frame"], digest(files), {"path": str(store)}))
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
    _check_fps(fps, f"{store}: attribute 'fps'")
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
        cam = _camera(str(view), {k: calib[k].sel(view=view).values for k in calib.data_vars}, f"{store}")
        if (cam.width, cam.height) != (ds.sizes["x"], ds.sizes["y"]):
            raise InputError(f"{store}: view {str(view)!r} is calibrated for {cam.width}x{cam.height} px but its images "
                             f"are {ds.sizes['x']}x{ds.sizes['y']}; fix 'width'/'height' or the images")


def _check_fps(fps, where: str) -> float:
    try:
        value = float(fps)
    except (TypeError, ValueError) as exc:
        raise InputError(f"{where} must be a number of frames per second, got {fps!r}") from exc
    if not np.isfinite(value) or value <= 0:
        raise InputError(f"{where} is {fps!r}; the frame rate must be a positive number of frames per second")
    return value


def _camera(view: str, values: Mapping[str, Any], where: str):
    """The checked camera of one view's calibration values (``CALIBRATION_VARIABLES``)."""
    try:
        return calibrated_camera(view, **{k: values[k] for k in ("fx", "fy", "cx", "cy", "dist", "cam_to_world",
                                                                 "width", "height")})
    except KeyError as exc:
        raise InputError(f"{where}: view {view!r} has no {exc.args[0]!r}; expected {CALIBRATION_HELP}") from None
    except CalibrationError as exc:
        raise InputError(f"{where}: {exc}; expected {CALIBRATION_HELP}") from exc


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
        folder = _folder(catalog, dataset)
        pattern = _pattern(dataset, "*")
        out = []
        for seq_dir in sorted(p for p in folder.glob(pattern) if (p / "calibration.yaml").is_file()):
            calib = _calibration(seq_dir)
            views = tuple(calib["views"])
            check_names(dataset.where, seq_dir.name, views, f" ({seq_dir})")  # before any view's folder is read
            numbers = {v: _view_frames(seq_dir, v, calib["cameras"][v]) for v in views}
            counts = {v: len(n) for v, n in numbers.items()}
            if len({(n[0], len(n)) if n else None for n in numbers.values()}) != 1:
                raise InputError(f"{seq_dir}: views have different frames {_spans(numbers)}; every view needs the "
                                 "same frame numbers")
            files = sorted((p.relative_to(seq_dir).as_posix(), p.stat().st_size, p.stat().st_mtime_ns)
                           for p in seq_dir.rglob("*") if p.is_file())
            out.append(SequenceInfo(seq_dir.name, views, counts[views[0]] if views else 0, digest(files),
                                    {"path": str(seq_dir)}))
        if not out:
            raise InputError(f"{dataset.where}: no sequence folders with calibration.yaml in {folder}")
        return out

    @staticmethod
    def read(dataset, seq: SequenceInfo, start: int, stop: int) -> xr.Dataset:
        import cv2

        seq_dir = Path(seq.spec["path"])
        calib = _calibration(seq_dir)
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


def _calibration(seq_dir: Path) -> dict:
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
    fps = _check_fps(calib["fps"], f"{path}: fps")
    cameras = {}
    for name, values in calib["views"].items():
        if not isinstance(values, dict):
            raise InputError(f"{path}: views.{name} must be a mapping; expected {CALIBRATION_HELP}")
        cameras[str(name)] = _camera(str(name), values, str(path))
    return {"fps": fps, "views": {str(k): v for k, v in calib["views"].items()}, "cameras": cameras}


# ---- studio -------------------------------------------------------------------------------
class StudioReader:
    options = ("sequences", "defaults", "layout")

    @staticmethod
    def discover(catalog, dataset) -> list[SequenceInfo]:
        from mocapflow.pipeline import studio_io

        return studio_io.discover(catalog, dataset)

    @staticmethod
    def read(dataset, seq: SequenceInfo, start: int, stop: int) -> xr.Dataset:
        from mocapflow.pipeline import studio_io

        return studio_io.read(dataset, seq, start, stop)


def _folder(catalog, dataset) -> Path:
    if "path" not in dataset.options:
        raise CatalogError(f"{dataset.where}: dataset kind {dataset.kind!r} needs 'path' (a folder of recordings)")
    folder = catalog.resolve_data_path(str(dataset.options["path"]), dataset.where)
    if not folder.is_dir():
        raise InputError(f"{dataset.where}: {folder} is not a folder; point 'path' at your recordings")
    return folder


# ---- marker files ----------------------------------------------------------------------------
_MARKER_FILES: BoundedCache[tuple, xr.Dataset] = BoundedCache(4)  # (path, size, mtime, up, labels) -> trajectories


class MarkerFileReader:
    """A folder of optical marker recordings (C3D, TRC), one sequence per file, as raw_markers (pipeline/marker_files.py).

    ``up``: which axis of the files is up (``z``, or ``y`` to turn Y-up files onto Z up); ``labels``: ``ignore``
    (unlabelled trajectories m000, m001, ...) or ``use``; ``frames``: ``[start, stop]``, the frames of each file
    to keep (a short take of a long trial); ``takes``: per file (by its id) its own ``up`` and ``frames``;
    ``prior``: a folder (inside data_roots) of monocular prior files, ``<id>.npz`` or ``<id>.json``
    (pipeline/prior_files.py), read as ``prior_joints`` for the ``file_prior`` stage. A catalog reads them with
    the source task ``ingest_markers``."""

    options = ("path", "pattern", "up", "labels", "frames", "takes", "prior")
    has_views = False  # trajectories, not sensor images: a sequence is one partition

    @staticmethod
    def discover(catalog, dataset) -> list[SequenceInfo]:
        folder = _folder(catalog, dataset)
        pattern = _pattern(dataset, "*.c3d")
        takes = dataset.options.get("takes") or {}
        if not isinstance(takes, Mapping):
            raise CatalogError(f"{dataset.where}.takes: expected a mapping of file ids to {{up, frames}}, got {takes!r}")
        prior = catalog.resolve_data_path(str(dataset.options["prior"]), f"{dataset.where}.prior") \
            if dataset.options.get("prior") is not None else None
        out = []
        for path in sorted(p for p in folder.glob(pattern) if p.is_file()):
            settings = MarkerFileReader._settings(dataset, path.stem)
            if prior is not None:
                from mocapflow.pipeline.prior_files import prior_path

                settings["prior"] = str(prior_path(prior, path.stem))
            ds = MarkerFileReader._load(dataset, path, settings)
            files = [file_digest(path)] + ([file_digest(Path(settings["prior"]))] if prior is not None else [])
            out.append(SequenceInfo(path.stem, (), ds.sizes["frame"], digest([files, settings]),
                                    {"path": str(path), **settings}))
        unknown = sorted(set(takes) - {s.id for s in out})
        if unknown:
            raise CatalogError(f"{dataset.where}.takes: {unknown} name no file matching {pattern!r} in {folder}; "
                               f"files: {[s.id for s in out]}")
        if not out:
            raise InputError(f"{dataset.where}: no marker files match {pattern!r} in {folder}")
        return out

    @staticmethod
    def _settings(dataset, take: str) -> dict:
        """A file's up axis, labels and frame range: the dataset's, overridden by ``takes.<id>``."""
        own = (dataset.options.get("takes") or {}).get(take) or {}
        if not isinstance(own, Mapping) or set(own) - {"up", "frames"}:
            raise CatalogError(f"{dataset.where}.takes.{take}: expected a mapping with 'up' and/or 'frames', got {own!r}")
        frames = own.get("frames", dataset.options.get("frames"))
        if frames is not None and not (isinstance(frames, (list, tuple)) and len(frames) == 2
                                       and all(isinstance(f, int) and not isinstance(f, bool) for f in frames)
                                       and 0 <= frames[0] < frames[1]):
            raise CatalogError(f"{dataset.where}: frames {frames!r} of {take!r} must be [start, stop] with "
                               "0 <= start < stop (frame numbers of the file, stop excluded)")
        return {"up": str(own.get("up", dataset.options.get("up", "z"))),
                "labels": str(dataset.options.get("labels", "ignore")),
                "frames": list(frames) if frames is not None else None}

    @staticmethod
    def _load(dataset, path: Path, settings: dict) -> xr.Dataset:
        from mocapflow.pipeline.marker_files import read_markers

        up, labels, frames = settings["up"], settings["labels"], settings["frames"]
        stat = path.stat()
        try:
            ds = _MARKER_FILES.get_or_make((str(path), stat.st_size, stat.st_mtime_ns, up, labels),
                                           lambda: read_markers(path, up=up, labels=labels))
        except InputError as exc:
            raise InputError(f"{dataset.where}: {exc}") from exc
        n_file = ds.sizes["frame"]
        if "prior" in settings:
            ds = ds.assign(prior_joints=(("frame", "joint", "xyz"), _prior_joints(dataset, settings["prior"], ds)),
                           joint=np.array(JOINT_NAMES, dtype=object))
        if frames is not None:
            if frames[1] > n_file:
                raise InputError(f"{dataset.where}: frames {frames} of {path} reach past its {n_file} frames; "
                                 "choose a range inside the recording")
            ds = ds.isel(frame=slice(*frames)).assign_coords(frame=np.arange(frames[1] - frames[0], dtype=np.int64))
        return ds

    @staticmethod
    def read(dataset, seq: SequenceInfo, start: int, stop: int) -> xr.Dataset:
        settings = {k: seq.spec[k] for k in ("up", "labels", "frames", "prior") if k in seq.spec}
        return MarkerFileReader._load(dataset, Path(seq.spec["path"]), settings).isel(frame=slice(start, stop))


def _prior_joints(dataset, path: str, markers: xr.Dataset) -> np.ndarray:
    """A take's prior file as (frame, joint, xyz) float32 over the whole recording."""
    from mocapflow.pipeline.prior_files import read_prior

    try:
        joints = read_prior(Path(path), frames=markers.sizes["frame"], fps=float(markers.attrs["fps"]))
    except InputError as exc:
        raise InputError(f"{dataset.where}.prior: {exc}") from exc
    return joints.astype(np.float32)


class StudioMarkersReader:
    """Unlabelled marker takes filmed on the studio's mesh body (UUO): a studio dataset whose sequences (and
    ``markers`` defaults) say how many markers, on which part, and what goes wrong while recording."""

    options = ("sequences", "defaults", "markers")
    has_views = False

    @staticmethod
    def discover(catalog, dataset) -> list[SequenceInfo]:
        from mocapflow.pipeline import studio_io

        return studio_io.discover_markers(catalog, dataset)

    @staticmethod
    def read(dataset, seq: SequenceInfo, start: int, stop: int) -> xr.Dataset:
        from mocapflow.pipeline import studio_io

        return studio_io.read_markers(dataset, seq, start, stop)


class StudioSuitReader:
    """Checkerboard-suit takes filmed in the studio by a ring of grey cameras (pipeline/suit_io.py)."""

    options = ("sequences", "defaults", "suit", "cameras", "look")

    @staticmethod
    def discover(catalog, dataset) -> list[SequenceInfo]:
        from mocapflow.pipeline import suit_io

        return suit_io.discover(catalog, dataset)

    @staticmethod
    def read(dataset, seq: SequenceInfo, start: int, stop: int) -> xr.Dataset:
        from mocapflow.pipeline import suit_io

        return suit_io.read(dataset, seq, start, stop)


class DeepMoCapReader:
    """The DeepMoCap dataset's recordings, one sequence per folder (pipeline/dmc_files.py): ``path`` and
    ``pattern`` as an image dataset's, ``intrinsics`` (the files hold none), ``fps`` (30), ``mirrored`` (true:
    flip the Kinect's mirrored images), ``up`` (z), ``unit`` of the extrinsics' positions (mm) and
    ``camera_axes`` (kinect: x left, y up; or opencv)."""

    options = ("path", "pattern", "intrinsics", "fps", "mirrored", "up", "unit", "camera_axes")

    @staticmethod
    def discover(catalog, dataset) -> list[SequenceInfo]:
        from mocapflow.pipeline import dmc_files

        folder = _folder(catalog, dataset)
        pattern = _pattern(dataset, "*")
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
                                    {"path": str(seq_dir), "views": views}))
        if not out:
            raise InputError(f"{dataset.where}: no DeepMoCap recordings in {folder} (folders matching {pattern!r} "
                             "with <view>.extrinsics files and <view>/ folders of numbered depth.pgm and mc_blob.png "
                             "files)")
        return out

    @staticmethod
    def read(dataset, seq: SequenceInfo, start: int, stop: int) -> xr.Dataset:
        from mocapflow.pipeline import dmc_files

        s = dmc_files.settings(dataset)
        return dmc_files.read(seq.spec["views"], s.mirrored, s.fps, start, stop)


DATASET_KINDS = {"studio": StudioReader, "zarr": ZarrReader, "images": ImageFolderReader, "markers": MarkerFileReader,
                 "studio_markers": StudioMarkersReader, "studio_suit": StudioSuitReader, "dmc": DeepMoCapReader}

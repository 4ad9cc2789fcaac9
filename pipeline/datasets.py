"""Dataset readers: where raw sequences come from, and the `frames` source stage.

Kinds:
  studio  sequences synthesized by the studio (tasks/studio) from per-sequence specs
  zarr    a folder of raw-sequence zarr stores (one per sequence, ``<id>.zarr``)
  images  a folder of sequences as 16-bit PNGs:
          ``<id>/calibration.yaml`` and ``<id>/<view>/{depth,ir}/<frame:06d>.png``

Each reader discovers sequences (id, views, frame count, fingerprint of the raw input) on the
driver, and reads a frame region on a worker. Only this module touches raw-input files. A reader's
``options`` names the catalog keys a dataset of its kind takes besides ``kind``; the catalog refuses
any other key when it is loaded.
"""

from __future__ import annotations

import fnmatch
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping

import numpy as np
import xarray as xr
import yaml

from mocapflow.pipeline.errors import CatalogError, InputError
from mocapflow.pipeline.hashing import digest
from mocapflow.pipeline.storage import check
from mocapflow.schemas import get_schema
from mocapflow.schemas.raw import make_raw_sequence


@dataclass(frozen=True)
class SequenceInfo:
    id: str
    views: tuple[str, ...]
    n_frames: int
    fingerprint: str
    spec: Mapping[str, Any]  # reader-specific (a studio spec, or a resolved path)


def discover(catalog, dataset, pattern: str | None = None) -> list[SequenceInfo]:
    """The sequences of ``dataset`` (optionally filtered by a glob on their ids)."""
    reader = DATASET_KINDS[dataset.kind]
    found = reader.discover(catalog, dataset)
    if pattern:
        found = [s for s in found if fnmatch.fnmatchcase(s.id, pattern)]
    return sorted(found, key=lambda s: s.id)


def read_frames(dataset, seq: SequenceInfo, start: int, stop: int) -> xr.Dataset:
    """Frames [start, stop) of ``seq`` (found by ``discover``) in the raw-sequence schema."""
    return DATASET_KINDS[dataset.kind].read(dataset, seq, start, stop)


# ---- zarr ---------------------------------------------------------------------------------
class ZarrReader:
    options = ("path", "pattern")

    @staticmethod
    def discover(catalog, dataset) -> list[SequenceInfo]:
        folder = _folder(catalog, dataset)
        pattern = dataset.options.get("pattern", "*.zarr")
        out = []
        for store in sorted(folder.glob(pattern)):
            ds = _open_raw(store)
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


# ---- images -------------------------------------------------------------------------------
class ImageFolderReader:
    options = ("path", "pattern")

    @staticmethod
    def discover(catalog, dataset) -> list[SequenceInfo]:
        folder = _folder(catalog, dataset)
        pattern = dataset.options.get("pattern", "*")
        out = []
        for seq_dir in sorted(p for p in folder.glob(pattern) if (p / "calibration.yaml").is_file()):
            calib = _calibration(seq_dir)
            views = tuple(calib["views"])
            counts = {v: len(list((seq_dir / v / "depth").glob("*.png"))) for v in views}
            n_frames = min(counts.values())
            if n_frames == 0 or len(set(counts.values())) != 1:
                raise InputError(f"{seq_dir}: views have different or zero frame counts {counts}; "
                                 "every view needs the same number of depth and IR PNGs")
            files = sorted((p.relative_to(seq_dir).as_posix(), p.stat().st_size, p.stat().st_mtime_ns)
                           for p in seq_dir.rglob("*") if p.is_file())
            out.append(SequenceInfo(seq_dir.name, views, n_frames, digest(files), {"path": str(seq_dir)}))
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
            for kind, sink in (("depth", depth), ("ir", ir)):
                files = sorted((seq_dir / view / kind).glob("*.png"))[start:stop]
                frames = [cv2.imread(str(f), cv2.IMREAD_UNCHANGED) for f in files]
                if any(f is None or f.dtype != np.uint16 for f in frames):
                    raise InputError(f"{seq_dir / view / kind}: every frame must be a readable 16-bit PNG")
                sink.append(np.stack(frames))
        fps = float(calib["fps"])
        return make_raw_sequence(np.stack(depth), np.stack(ir), calib["views"], fps, start)


def _calibration(seq_dir: Path) -> dict:
    path = seq_dir / "calibration.yaml"
    try:
        calib = yaml.safe_load(path.read_text())
        calib["views"] = {str(k): v for k, v in calib["views"].items()}
        float(calib["fps"])
    except (OSError, yaml.YAMLError, KeyError, TypeError, ValueError) as exc:
        raise InputError(f"{path}: expected 'fps' and 'views: {{name: {{fx, fy, cx, cy, dist, cam_to_world, "
                         f"width, height}}}}' ({exc})") from exc
    return calib


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


DATASET_KINDS = {"studio": StudioReader, "zarr": ZarrReader, "images": ImageFolderReader}

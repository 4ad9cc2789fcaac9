"""The UUO system's dataset kind ``markers``: a folder of optical marker recordings (C3D, TRC) as raw_markers."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path
from typing import Mapping

import numpy as np
import xarray as xr

from mocapflow.pipeline.datasets import SequenceInfo, data_folder, data_pattern
from mocapflow.pipeline.errors import CatalogError, InputError
from mocapflow.pipeline.hashing import digest, file_digest
from mocapflow.systems.uuo.marker_files import MAX_COORDINATE_M, read_markers
from mocapflow.systems.uuo.prior_files import prior_path, read_prior
from mocapflow.tasks.shared.body import JOINT_NAMES
from mocapflow.tasks.shared.cache import BoundedCache

# ---- marker files ----------------------------------------------------------------------------
_MARKER_FILES: BoundedCache[tuple, xr.Dataset] = BoundedCache(4)  # (path, size, mtime, up, labels) -> trajectories


class MarkerFileReader:
    """A folder of optical marker recordings (C3D, TRC), one sequence per file, as raw_markers (systems/uuo/marker_files.py).

    ``path``: the folder, or a list of folders (each inside data_roots), whose files matching ``pattern`` (a glob,
    ``*.c3d`` by default; with several folders one glob for all or a list of one per folder) are the takes, each
    named by its file's name without the extension: a name found twice is refused. ``up``: which axis of the files
    is up (``auto``, the default: found from the markers; ``z``; or ``y`` to turn Y-up files onto Z up); ``labels``:
    ``ignore`` (unlabelled trajectories m000, m001, ...) or ``use``; ``frames``: ``[start, stop]``, the frames of each file
    to keep (a short take of a long trial); ``takes``: per file (by its id) its own ``up`` and ``frames``;
    ``prior``: a folder (inside data_roots) of monocular prior files, ``<id>.npz`` or ``<id>.json``
    (systems/uuo/prior_files.py), read as ``prior_joints`` for the ``file_prior`` stage; ``max_coordinate_m``: the
    farthest a coordinate may lie from the origin on any axis (20 m), a file with a sample beyond it refused. A
    catalog reads them with the source task ``ingest_markers``."""

    options = ("path", "pattern", "up", "labels", "frames", "takes", "prior", "max_coordinate_m")
    has_views = False  # trajectories, not sensor images: a sequence is one partition

    @staticmethod
    def discover(catalog, dataset) -> list[SequenceInfo]:
        sources = _folders(catalog, dataset)
        takes = dataset.options.get("takes") or {}
        if not isinstance(takes, Mapping):
            raise CatalogError(f"{dataset.where}.takes: expected a mapping of file ids to {{up, frames}}, got {takes!r}")
        prior = catalog.resolve_data_path(str(dataset.options["prior"]), f"{dataset.where}.prior") \
            if dataset.options.get("prior") is not None else None
        out = []
        for path in _marker_files(dataset, sources):
            settings = MarkerFileReader._settings(dataset, path.stem)
            if prior is not None:
                settings["prior"] = str(prior_path(prior, path.stem))
            ds = MarkerFileReader._load(dataset, path, settings)
            files = [file_digest(path)] + ([file_digest(Path(settings["prior"]))] if prior is not None else [])
            out.append(SequenceInfo(path.stem, (), ds.sizes["frame"], digest([files, settings]),
                                    {"path": str(path), **settings}))
        where = "; ".join(f"{pattern!r} in {folder}" for folder, pattern in sources)
        unknown = sorted(set(takes) - {s.id for s in out})
        if unknown:
            raise CatalogError(f"{dataset.where}.takes: {unknown} name no file matching {where}; "
                               f"files: {[s.id for s in out]}")
        if not out:
            raise InputError(f"{dataset.where}: no marker files match {where}")
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
        return {"up": str(own.get("up", dataset.options.get("up", "auto"))),
                "labels": str(dataset.options.get("labels", "ignore")),
                "frames": list(frames) if frames is not None else None}

    @staticmethod
    def _load(dataset, path: Path, settings: dict) -> xr.Dataset:
        up, labels, frames = settings["up"], settings["labels"], settings["frames"]
        bound = _max_coordinate(dataset)
        stat = path.stat()
        try:
            ds = _MARKER_FILES.get_or_make((str(path), stat.st_size, stat.st_mtime_ns, up, labels, bound),
                                           lambda: read_markers(path, up=up, labels=labels, max_coordinate_m=bound))
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


def _folders(catalog, dataset) -> list[tuple[Path, str]]:
    """The dataset's folders, each with its glob: ``path`` one folder or a list of folders (each checked as one
    folder's path is: inside data_roots, an existing folder), ``pattern`` one glob for every folder or a list of one
    glob per folder."""
    paths, pattern = dataset.options.get("path"), dataset.options.get("pattern", "*.c3d")
    if not isinstance(paths, (list, tuple)):
        if isinstance(pattern, (list, tuple)):
            raise CatalogError(f"{dataset.where}.pattern: a list of globs needs 'path' to be a list of as many folders, "
                               f"got path {paths!r}; give one glob, e.g. '*.c3d'")
        return [(data_folder(catalog, dataset), data_pattern(dataset, "*.c3d"))]
    if not paths or not all(isinstance(p, str) and p for p in paths):
        raise CatalogError(f"{dataset.where}.path: expected a folder or a non-empty list of folders, got {paths!r}")
    patterns = list(pattern) if isinstance(pattern, (list, tuple)) else [pattern] * len(paths)
    if len(patterns) != len(paths):
        raise CatalogError(f"{dataset.where}.pattern: {len(patterns)} globs for the {len(paths)} folders of 'path'; "
                           "give one glob for all of them or one per folder, in the order of 'path'")
    out = []
    for i, (path, glob) in enumerate(zip(paths, patterns)):
        one = replace(dataset, options={**dataset.options, "path": path, "pattern": glob},
                      where=f"{dataset.where}.path[{i}]")
        out.append((data_folder(catalog, one), data_pattern(one, "*.c3d")))
    if len({folder for folder, _ in out}) < len(out):
        raise CatalogError(f"{dataset.where}.path: a folder is named twice in {paths!r}; name each folder once")
    return out


def _marker_files(dataset, sources: list[tuple[Path, str]]) -> list[Path]:
    """The files matching each folder's glob, folder by folder in the order of ``path``, each folder's in name order;
    two files with one id (the name without its extension) are refused, naming both."""
    found: dict[str, Path] = {}
    for folder, pattern in sources:
        for path in sorted(p for p in folder.glob(pattern) if p.is_file()):
            if path.stem in found:
                raise CatalogError(f"{dataset.where}: take {path.stem!r} is both {found[path.stem]} and {path}; a take "
                                   "is named by its file: rename one of them or narrow a pattern")
            found[path.stem] = path
    return list(found.values())


def _max_coordinate(dataset) -> float:
    """The dataset's ``max_coordinate_m``: a positive number of metres (MAX_COORDINATE_M when absent)."""
    value = dataset.options.get("max_coordinate_m", MAX_COORDINATE_M)
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not 0 < value < float("inf"):
        raise CatalogError(f"{dataset.where}.max_coordinate_m: expected a positive number of metres (the farthest a "
                           f"marker may lie from the origin on any axis), got {value!r}; e.g. {MAX_COORDINATE_M:g}")
    return float(value)


def _prior_joints(dataset, path: str, markers: xr.Dataset) -> np.ndarray:
    """A take's prior file as (frame, joint, xyz) float32 over the whole recording."""
    try:
        joints = read_prior(Path(path), frames=markers.sizes["frame"], fps=float(markers.attrs["fps"]))
    except InputError as exc:
        raise InputError(f"{dataset.where}.prior: {exc}") from exc
    return joints.astype(np.float32)

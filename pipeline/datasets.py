"""Datasets: where a stage's raw sequences come from, and the source stages that read them.

A dataset's ``kind`` names a reader that some system registers (``registry.DatasetKind``: the DeepMoCap
system's ``zarr``, ``images`` and ``dmc``; UUO's ``markers``; the studio's ``studio``, ``studio_markers`` and
``studio_suit``; a plug-in's own). Each reader discovers sequences (id, views, frame count, fingerprint of the raw
input) on the driver, and reads a frame region on a worker. Discovery checks the raw input before any stage runs,
each failure an error naming the file, the key or the frame and the fix.

Sequence ids and view names become parts of paths (partitions, export files), so both must match
``NAME_RULE``: letters, digits, ``_``, ``-`` and ``.``, not starting with ``.``; a sequence's view
names are distinct, and a sequence has at least one frame. A dataset's ``pattern`` matches names inside its
``path`` and may not leave it (no ``..``, not absolute): :func:`data_folder` and :func:`data_pattern` give them
to every reader.

A reader's ``options`` names the catalog keys a dataset of its kind takes besides ``kind``; the catalog refuses
any other key when it is loaded.
"""

from __future__ import annotations

import fnmatch
import re
from dataclasses import dataclass
from pathlib import Path, PurePosixPath
from typing import Any, Mapping

import numpy as np

from mocapflow.pipeline import registry
from mocapflow.pipeline.errors import CatalogError, InputError
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
    image: tuple[int, int] | None = None  # (height, width) px of its views' images, as its reader states them


def discover(catalog, dataset, pattern: str | None = None) -> list[SequenceInfo]:
    """The sequences of ``dataset`` (optionally filtered by a glob on their ids), their names checked."""
    reader = registry.dataset_kind(dataset.kind)
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
    check_names(dataset.where, seq.id, seq.views, source, getattr(registry.dataset_kind(dataset.kind), "has_views", True))
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


def data_pattern(dataset, default: str) -> str:
    """A dataset's ``pattern``: a glob of names inside its folder, never leaving it."""
    pattern = str(dataset.options.get("pattern", default))
    parts = PurePosixPath(pattern.replace("\\", "/")).parts
    if not pattern or PurePosixPath(pattern).is_absolute() or Path(pattern).is_absolute() or ".." in parts \
            or pattern.startswith("~"):
        raise CatalogError(f"{dataset.where}.pattern: {pattern!r} leaves the dataset's folder; a pattern matches names "
                           f"inside 'path' (e.g. {default!r}): drop the '..', or point 'path' at the other folder "
                           "(inside data_roots)")
    return pattern


def read_frames(dataset, seq: SequenceInfo, start: int, stop: int):
    """Frames [start, stop) of ``seq`` (found by ``discover``) in the raw-sequence schema."""
    return registry.dataset_kind(dataset.kind).read(dataset, seq, start, stop)


def data_folder(catalog, dataset) -> Path:
    if "path" not in dataset.options:
        raise CatalogError(f"{dataset.where}: dataset kind {dataset.kind!r} needs 'path' (a folder of recordings)")
    folder = catalog.resolve_data_path(str(dataset.options["path"]), dataset.where)
    if not folder.is_dir():
        raise InputError(f"{dataset.where}: {folder} is not a folder; point 'path' at your recordings")
    return folder


def check_fps(fps, where: str) -> float:
    try:
        value = float(fps)
    except (TypeError, ValueError) as exc:
        raise InputError(f"{where} must be a number of frames per second, got {fps!r}") from exc
    if not np.isfinite(value) or value <= 0:
        raise InputError(f"{where} is {fps!r}; the frame rate must be a positive number of frames per second")
    return value


def checked_camera(view: str, values: Mapping[str, Any], where: str):
    """The checked camera of one view's calibration values (``CALIBRATION_VARIABLES``)."""
    try:
        return calibrated_camera(view, **{k: values[k] for k in ("fx", "fy", "cx", "cy", "dist", "cam_to_world",
                                                                 "width", "height")})
    except KeyError as exc:
        raise InputError(f"{where}: view {view!r} has no {exc.args[0]!r}; expected {CALIBRATION_HELP}") from None
    except CalibrationError as exc:
        raise InputError(f"{where}: {exc}; expected {CALIBRATION_HELP}") from exc

"""Content-addressed artifact storage on any fsspec root.

Layout of one artifact version (one stage partition under one cache key)::

    <root>/<stage>/<key>/lineage.json      key components, partition, written before any data
    <root>/<stage>/<key>/data.zarr/        the xarray Dataset (zarr v3), chunked along frames
    <root>/<stage>/<key>/_init             template (metadata + frame-less arrays) is written; its chunks' digests
    <root>/<stage>/<key>/_regions/A-B      frames [A, B) are written (marker written after the data): its seconds and
                                           the digest of each chunk it wrote (pipeline/integrity.py)
    <root>/<stage>/<key>/digests.json      every chunk's digest, gathered at the commit; reads check chunks against it
    <root>/<stage>/<key>/_COMPLETE         every region is committed; lineage is in the zarr attrs
    <root>/<stage>/<key>/_DAMAGED          `mocapflow verify` found damaged chunks; their regions are to be written again
    <root>/<stage>/<key>/.lock             held while a run writes this version (a lease: pipeline/locks.py)
    <root>/runs/<run id>.json              a live run's lease on every version it reads or writes (and a gc's
                                           presence), renewed while it runs: `mocapflow gc` deletes none of them

A version is read only when ``_COMPLETE`` exists; a region is trusted only when its marker
exists, so a run killed at any point resumes at region granularity and never reads a partial
region as done. Several versions of a partition live side by side (swap A -> B -> A reuses A).
"""

from __future__ import annotations

import json
import logging
import os
import time
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Iterator

import fsspec
import numpy as np
import xarray as xr

from mocapflow.pipeline.errors import LockError, SchemaError, StorageError
from mocapflow.pipeline.integrity import (RecordingStore, VerifyingStore, Where, chunk_problem, digest, is_chunk,
                                         zarr_store)
from mocapflow.pipeline.locks import LeasedLock, RunLease, describe, read_run_leases
from mocapflow.schemas import ArtifactSchema, SchemaViolation
from mocapflow.tasks.shared.cache import BoundedCache

log = logging.getLogger(__name__)

# The zarr releases region writes are tested on (pyproject.toml pins the same range): write_zarr_region uses zarr's
# internal zarr.core.sync.sync and AsyncArray.with_config (3.1.6 on). Widen it only after tests/pipeline/test_storage.py
# passes on the new release.
ZARR_RANGE = ">=3.1.6,<3.2"

# Complete versions opened by this process (lazily, checked against their schema), for the many regions that read
# them: opening one reads every array's metadata. Keyed by the completion stamp, so a version deleted and written
# again is opened afresh; (zarr target, schema name, stamp) -> Dataset.
_OPENED: BoundedCache[tuple[str, str, str], xr.Dataset] = BoundedCache(64)


@dataclass(frozen=True)
class Damage:
    """A stored chunk that differs from its digest: its ``group`` (``"init"`` or a region ``"A-B"``), zarr key
    and what is wrong."""

    group: str
    chunk: str
    problem: str


@dataclass(frozen=True)
class VersionInfo:
    stage: str
    key: str
    partition: str
    complete: bool
    lineage: dict


LOG_FOLDER = "logs"  # each run's log file, <root>/logs/run-<time>.log (runlog.py)
RUNS_FOLDER = "runs"  # each live run's lease on the versions it holds, <root>/runs/<run id>.json
GC_WAIT_POLL_S = 0.2  # how often a starting run looks again whether a gc still runs


class Store:
    """One storage root (a local folder or any fsspec URL)."""

    def __init__(self, root: str):
        self.root = root
        self.fs, self.base = fsspec.core.url_to_fs(root, **_storage_options(root))
        self.local = "file" in _protocols(self.fs)

    # ---- paths -------------------------------------------------------------------------
    def version_dir(self, stage: str, key: str) -> str:
        return f"{self.base.rstrip('/')}/{stage}/{key}"

    def _zarr_target(self, stage: str, key: str) -> str:
        path = f"{self.version_dir(stage, key)}/data.zarr"
        return path if self.local else self.fs.unstrip_protocol(path)

    def _marker(self, stage: str, key: str, name: str) -> str:
        return f"{self.version_dir(stage, key)}/{name}"

    # ---- state ---------------------------------------------------------------------------
    def is_complete(self, stage: str, key: str) -> bool:
        return self.fs.exists(self._marker(stage, key, "_COMPLETE"))

    def region_done(self, stage: str, key: str, start: int, stop: int) -> bool:
        return self.fs.exists(self._marker(stage, key, f"_regions/{start:08d}-{stop:08d}"))

    def regions_done(self, stage: str, key: str) -> int:
        try:
            return len(self.fs.ls(self._marker(stage, key, "_regions"), detail=False))
        except FileNotFoundError:
            return 0

    def versions(self, stage: str) -> list[VersionInfo]:
        """Every stored version of ``stage`` (complete or not) with its lineage."""
        out = []
        for path in self.fs.glob(f"{self.base.rstrip('/')}/{stage}/*/lineage.json"):
            key = path.rstrip("/").split("/")[-2]
            try:
                lineage = json.loads(self.fs.cat_file(path))
            except (OSError, ValueError):
                continue
            out.append(VersionInfo(stage, key, lineage.get("partition", "?"), self.is_complete(stage, key), lineage))
        return out

    def stages_on_disk(self) -> list[str]:
        try:
            entries = self.fs.ls(self.base, detail=True)
        except FileNotFoundError:
            return []
        names = sorted(e["name"].rstrip("/").split("/")[-1] for e in entries if e["type"] == "directory")
        # The runs' log files (runlog.py) and leases share the root; their folders are stages only where they hold
        # versions.
        return [n for n in names if n not in (LOG_FOLDER, RUNS_FOLDER)
                or self.fs.glob(f"{self.base.rstrip('/')}/{n}/*/lineage.json")]

    def _put(self, path: str, data: bytes) -> None:
        self.fs.makedirs(path.rsplit("/", 1)[0], exist_ok=True)
        self.fs.pipe_file(path, data)

    def remove_version(self, stage: str, key: str) -> None:
        """Delete a version, its completion marker first (a reader sees it complete or absent, never half gone)."""
        if self.fs.exists(self._marker(stage, key, "_COMPLETE")):
            self.fs.rm_file(self._marker(stage, key, "_COMPLETE"))
        self.fs.rm(self.version_dir(stage, key), recursive=True)

    def writable(self) -> bool:
        """Whether this process may write under the root: a local root's nearest existing folder is writable (a
        read-only mount or folder is not); a remote root is taken as writable, its writes name their own errors."""
        if not self.local:
            return True
        path = Path(self.base)
        while not path.exists() and path.parent != path:
            path = path.parent
        return os.access(path, os.W_OK)

    def refuse_writes(self, what: str) -> StorageError:
        """The error for ``what`` (e.g. "3 partition(s) to compute") in a root this process cannot write."""
        return StorageError(f"the storage root {self.root} is read-only (or not writable by this user) and {what}; "
                            "make it writable, or pass --set storage.root=<a writable folder>")

    # ---- run leases ----------------------------------------------------------------------
    def _runs_folder(self) -> str:
        return f"{self.base.rstrip('/')}/{RUNS_FOLDER}"

    @contextmanager
    def run_lease(self, label: str, versions: list[tuple[str, str]], kind: str = "run",
                  run_id: str | None = None) -> Iterator[str]:
        """Hold ``versions`` (stage, key) for the enclosed run, whose id it yields: `mocapflow gc` deletes none of
        them while the lease lives (pipeline/locks.py, RunLease). ``kind="gc"``: a gc's presence, held while it
        deletes; a run starting meanwhile waits for that gc to end before it looks at any version (each writes
        its lease before reading the other's, so one of the two always sees the other)."""
        lease = RunLease(self.fs, self._runs_folder(), self.local, label, kind, versions, run_id)
        try:
            lease.start()
        except OSError as exc:
            raise StorageError(f"cannot write the run lease {lease.path} in {self.root} ({exc.strerror or exc}); "
                               f"free space there or make it writable, and run again") from exc
        try:
            if kind == "run":
                self._wait_for_gc(lease.run_id)
            yield lease.run_id
        finally:
            lease.end()

    def live_leases(self, kind: str | None = None) -> list[dict]:
        """The live run leases (of ``kind``); dead ones are deleted on the way."""
        live, dead = read_run_leases(self.fs, self._runs_folder())
        for path in dead:
            log.info("deleting the dead run lease %s", path)
            try:
                self.fs.rm_file(path)
            except FileNotFoundError:
                continue
        return [info for info in live if kind is None or info.get("kind") == kind]

    def held_versions(self) -> dict[tuple[str, str], str]:
        """(stage, key) -> the live run holding it, described, for every version a live run lease holds."""
        held: dict[tuple[str, str], str] = {}
        for info in self.live_leases("run"):
            for stage, key in info.get("versions", []):
                held.setdefault((stage, key), f"run {info.get('run_id')} ({describe(info)})")
        return held

    def _wait_for_gc(self, run_id: str) -> None:
        logged = False
        while True:
            gcs = [info for info in self.live_leases("gc") if info.get("run_id") != run_id]
            if not gcs:
                return
            if not logged:
                log.warning("waiting for `mocapflow gc` (%s) to finish before reading %s", describe(gcs[0]), self.root)
                logged = True
            time.sleep(GC_WAIT_POLL_S)

    # ---- writing -------------------------------------------------------------------------
    def begin(self, stage: str, key: str, lineage: dict) -> None:
        self.fs.makedirs(self.version_dir(stage, key), exist_ok=True)
        self._put(self._marker(stage, key, "lineage.json"), json.dumps(lineage, indent=1).encode())

    def write_region(self, stage: str, key: str, schema: ArtifactSchema, ds: xr.Dataset,
                     n_frames: int, start: int, stop: int, seconds: float = 0.0,
                     cpu_seconds: float | None = None) -> None:
        """Write frames [start, stop) of ``ds`` (validated), initializing the store on first use; the region's
        marker records the ``seconds`` it took, the worker process's ``cpu_seconds`` meanwhile (where measured)
        and the digest of every chunk written (``_init``'s, those of the template)."""
        check(schema, ds, f"output of stage {stage!r} frames {start}-{stop}")
        frames = ds["frame"].values if "frame" in ds.coords else None
        if frames is not None and not np.array_equal(frames, np.arange(start, stop)):
            raise SchemaError(f"output of stage {stage!r} for frames {start}-{stop} ({self.version_dir(stage, key)}) "
                              f"has frame coordinate {_frames_text(frames)}, expected {start}..{stop - 1}; "
                              "the task must return exactly the frames of its region, in order")
        target = self._zarr_target(stage, key)
        digests: dict[str, str] = {}
        if not self.fs.exists(self._marker(stage, key, "_init")):
            if self.fs.exists(self._marker(stage, key, "_regions")):
                self.fs.rm(self._marker(stage, key, "_regions"), recursive=True)
            whole = start == 0 and stop == n_frames
            init_digests: dict[str, str] = {}
            init_zarr(target, schema, ds, n_frames, with_data=whole, digests=init_digests)
            self._put(self._marker(stage, key, "_init"), json.dumps({"chunks": init_digests}).encode())
            if not whole:
                write_zarr_region(target, ds, start, stop, digests=digests)
        else:
            write_zarr_region(target, ds, start, stop, digests=digests)
        marker = {"seconds": round(seconds, 6), "chunks": digests}
        if cpu_seconds is not None:
            marker["cpu_seconds"] = round(cpu_seconds, 6)
        self._put(self._marker(stage, key, f"_regions/{start:08d}-{stop:08d}"), json.dumps(marker).encode())

    def region_seconds(self, stage: str, key: str) -> float:
        """The seconds recorded by the written regions of a version (0 for markers without)."""
        total = 0.0
        for path in self.fs.glob(self._marker(stage, key, "_regions/*")):
            total += _region_record(self.fs.cat_file(path)).get("seconds", 0.0)
        return total

    def region_cpu_seconds(self, stage: str, key: str) -> float | None:
        """The worker's CPU seconds recorded by the written regions of a version; None where a region has none
        (written before they were recorded)."""
        records = [_region_record(self.fs.cat_file(p)) for p in self.fs.glob(self._marker(stage, key, "_regions/*"))]
        if not records or any("cpu_seconds" not in r for r in records):
            return None
        return sum(r["cpu_seconds"] for r in records)

    def pending_lineage(self, stage: str, key: str) -> dict:
        """The lineage written by ``begin`` ({} if none)."""
        try:
            return json.loads(self.fs.cat_file(self._marker(stage, key, "lineage.json")))
        except (OSError, ValueError):
            return {}

    def commit(self, stage: str, key: str, lineage: dict) -> None:
        """Record lineage in the zarr attrs and mark the version complete (last write)."""
        import zarr

        group = zarr.open_group(self._zarr_target(stage, key), mode="r+", zarr_format=3)
        group.attrs["mocapflow_lineage"] = json.loads(json.dumps(lineage))
        self._put(self._marker(stage, key, "lineage.json"), json.dumps(lineage, indent=1).encode())
        recorded = {**self._collect_digests(stage, key), "meta": self._metadata_digests(stage, key)}
        self._put(self._marker(stage, key, "digests.json"), json.dumps(recorded).encode())
        self._put(self._marker(stage, key, "_COMPLETE"), str(time.time()).encode())
        self.drop_checkpoint(stage, key)  # the committed artifact supersedes it
        if self.fs.exists(self._marker(stage, key, "_DAMAGED")):
            self.fs.rm_file(self._marker(stage, key, "_DAMAGED"))

    # ---- a long task's checkpoint ----------------------------------------------------------------
    def save_checkpoint(self, stage: str, key: str, data: bytes) -> None:
        """Keep ``data`` as the checkpoint of an uncommitted version (written whole, then moved in place)."""
        path = self._marker(stage, key, "_checkpoint")
        self._put(path + ".partial", data)
        self.fs.mv(path + ".partial", path)

    def checkpoint(self, stage: str, key: str) -> bytes | None:
        """The checkpoint saved for a version, None if there is none."""
        try:
            return self.fs.cat_file(self._marker(stage, key, "_checkpoint"))
        except FileNotFoundError:
            return None

    def drop_checkpoint(self, stage: str, key: str) -> None:
        if self.fs.exists(self._marker(stage, key, "_checkpoint")):
            self.fs.rm_file(self._marker(stage, key, "_checkpoint"))

    # ---- reading -------------------------------------------------------------------------
    def open(self, stage: str, key: str, schema: ArtifactSchema, partial: bool = False) -> xr.Dataset:
        """The complete artifact, lazily indexed and checked against ``schema``. ``partial``: also an artifact
        still being written (only its written regions hold data; the caller reads no other frames)."""
        stamp = self._completed(stage, key)
        begun = partial and stamp is None and self.fs.exists(self._marker(stage, key, "_init"))
        if stamp is None and not begun:
            if not self.fs.exists(self.version_dir(stage, key)):
                raise StorageError(f"artifact {stage}/{key} is not complete in {self.root}: it was never computed, "
                                   "or deleted while a run needed it (by hand, or a `mocapflow gc` of a release "
                                   f"without run leases); run again (`mocapflow run --until {stage}`) to compute it")
            raise StorageError(f"artifact {stage}/{key} is not complete in {self.root}; "
                               f"run `mocapflow run --until {stage}` to produce it")
        target = self._zarr_target(stage, key)
        if stamp is None:  # a version still being written is opened afresh each time
            ds = self._open_checked(stage, key, schema, target)
        else:
            ds = _OPENED.get_or_make((target, schema.name, stamp), lambda: self._open_checked(stage, key, schema, target))
        return ds.copy(deep=False)  # loading the caller's copy leaves the kept one lazy

    def _open_checked(self, stage: str, key: str, schema: ArtifactSchema, target: str) -> xr.Dataset:
        """The version, each chunk checked against its digest as it is read (pipeline/integrity.py)."""
        try:
            ds = xr.open_zarr(self._verified(stage, key, target), consolidated=False, chunks=None, zarr_format=3)
        except (OSError, ValueError, KeyError) as exc:
            raise StorageError(f"artifact {stage}/{key} in {self.root} is unreadable ({exc}); "
                               f"delete {self.version_dir(stage, key)} and rerun") from exc
        check(schema, ds, f"stored artifact {stage}/{key}")
        return ds

    def _verified(self, stage: str, key: str, target: str):
        """A zarr store reading ``target`` that checks every recorded chunk; ``target`` itself for a version
        written before digests were recorded."""
        expected = {chunk: d for chunks in _chunk_groups(self.digests(stage, key)).values() for chunk, d in chunks.items()}
        if not expected:
            return target

        where = Where(stage, key, self.pending_lineage(stage, key).get("partition", "?"), self.root)
        return VerifyingStore(zarr_store(target, read_only=True), expected, where)

    def _completed(self, stage: str, key: str) -> str | None:
        """The ``_COMPLETE`` marker's time stamp, None while the version is not complete."""
        try:
            return self.fs.cat_file(self._marker(stage, key, "_COMPLETE")).decode()
        except FileNotFoundError:
            return None

    # ---- integrity -------------------------------------------------------------------------
    def digests(self, stage: str, key: str) -> dict:
        """The recorded chunk digests of a version: ``{"init": {chunk: digest}, "regions": {"A-B": {chunk:
        digest}}}``, a complete version's from its ``digests.json``; empty for versions written before digests."""
        if self._completed(stage, key) is not None:
            try:
                return json.loads(self.fs.cat_file(self._marker(stage, key, "digests.json")))
            except FileNotFoundError:
                return {}
        return self._collect_digests(stage, key)

    def _collect_digests(self, stage: str, key: str) -> dict:
        try:
            init = _region_record(self.fs.cat_file(self._marker(stage, key, "_init"))).get("chunks", {})
        except FileNotFoundError:
            init = {}
        regions = {path.rstrip("/").split("/")[-1]: _region_record(self.fs.cat_file(path)).get("chunks", {})
                   for path in self.fs.glob(self._marker(stage, key, "_regions/*"))}
        return {"init": init, "regions": regions}

    def _metadata_digests(self, stage: str, key: str) -> dict[str, str]:
        """The digest of every metadata file of a version's zarr group (its own and each array's ``zarr.json``:
        dtypes, codecs, shapes, attributes), keyed like chunks."""

        base = f"{self.version_dir(stage, key)}/data.zarr"
        names = [path[len(base) + 1:] for path in self.fs.find(base)]
        paths = {name: f"{base}/{name}" for name in names if not is_chunk(name)}
        stored = self.fs.cat(list(paths.values())) if paths else {}
        return {name: digest(stored[path]) for name, path in sorted(paths.items())}

    def check_chunks(self, stage: str, key: str, groups: dict[str, dict[str, str]]) -> list[Damage]:
        """The chunks of ``groups`` (``"init"`` or a region ``"A-B"`` -> {chunk: digest}) whose stored bytes are
        missing or differ from their digest."""

        base = f"{self.version_dir(stage, key)}/data.zarr"
        paths = sorted({f"{base}/{chunk}" for chunks in groups.values() for chunk in chunks})
        stored = self.fs.cat(paths, on_error="return") if paths else {}
        damage = []
        for group, chunks in groups.items():  # a chunk several regions write (the frame coordinate) in each
            for chunk, want in chunks.items():
                data = stored.get(f"{base}/{chunk}")
                problem = chunk_problem(None if isinstance(data, Exception) else data, want)
                if problem is not None:
                    damage.append(Damage(group, chunk, problem))
        return damage

    def verify(self, stage: str, key: str) -> list[Damage] | None:
        """The damaged chunks of a complete version (None: it has no digests to check)."""
        recorded = self.digests(stage, key)
        if not recorded:
            return None
        return self.check_chunks(stage, key, _chunk_groups(recorded))

    def resume_region(self, stage: str, key: str, start: int, stop: int) -> bool:
        """Whether frames [start, stop) are written and intact, with the template (its frame-less arrays and frame
        coordinate: small); a damaged region's markers are deleted, so that the caller writes it again (every
        region, if the template is damaged)."""
        if not self.region_done(stage, key, start, stop):
            return False
        recorded = self._collect_digests(stage, key)
        name = f"{start:08d}-{stop:08d}"
        groups = {"init": recorded["init"], name: recorded["regions"].get(name, {})}
        damage = self.check_chunks(stage, key, groups)
        if not damage:
            return True
        log.warning("%s/%s: written frames %d-%d are damaged (%s); writing them again", stage, key, start, stop,
                    "; ".join(f"{d.chunk} {d.problem}" for d in damage[:3]))
        self._forget(stage, key, damage)
        return False

    def mark_damaged(self, stage: str, key: str, damage: list[Damage], label: str) -> None:
        """Record ``damage`` in ``_DAMAGED`` and make the version incomplete, its damaged regions unwritten, so
        that the next run writes exactly those again (the whole version if the template is damaged)."""
        with self.lock(stage, key, label):
            record = {"found": time.strftime("%Y-%m-%dT%H:%M:%S"),
                      "chunks": {d.chunk: f"{d.group}: {d.problem}" for d in damage}}
            self._put(self._marker(stage, key, "_DAMAGED"), json.dumps(record, indent=1).encode())
            for name in ("_COMPLETE", "digests.json"):
                if self.fs.exists(self._marker(stage, key, name)):
                    self.fs.rm_file(self._marker(stage, key, name))
            self._forget(stage, key, damage)

    def is_damaged(self, stage: str, key: str) -> bool:
        return self.fs.exists(self._marker(stage, key, "_DAMAGED"))

    def _forget(self, stage: str, key: str, damage: list[Damage]) -> None:
        """Delete the markers of the damaged regions (all of them and ``_init`` if the template or the metadata is
        damaged)."""
        if any(d.group in ("init", "meta") for d in damage):
            for name in ("_init", "_regions"):
                if self.fs.exists(self._marker(stage, key, name)):
                    self.fs.rm(self._marker(stage, key, name), recursive=True)
            return
        for group in sorted({d.group for d in damage}):
            if self.fs.exists(self._marker(stage, key, f"_regions/{group}")):
                self.fs.rm_file(self._marker(stage, key, f"_regions/{group}"))

    # ---- locking -------------------------------------------------------------------------
    @contextmanager
    def lock(self, stage: str, key: str, label: str, lease_s: float | None = None) -> Iterator[None]:
        """Exclusive lock of one version, held as a lease (pipeline/locks.py).

        The holder renews the lease every ``lease_s / 6`` seconds from a daemon thread (``lease_s``: by default
        ``$MOCAPFLOW_LOCK_LEASE_S`` or 60 s). Another run that reaches the version while the lease runs gets a
        LockError naming the holder; a lock whose lease ran out is stale on any host, and one left by a dead
        process of this host is stale at once. A stale lock is taken over atomically: the contender claims it
        by creating ``.lock.takeover-<holder's token>`` exclusively, checks again that it is stale, and moves its
        own lock over it with ``os.replace``; a second contender fails to create the claim, or finds the new lock
        live, and backs off, so two never both win. On a local or mounted folder these are ``O_EXCL`` creates
        and renames; on S3 the creates are conditional PUTs (``If-None-Match: *``) and a PUT replaces an object
        whole, for the same guarantee; on a server that ignores the condition, or another object store, the
        create is a look then a write: best effort (pipeline/locks.py, docs/engine.md, Object stores).
        A holder that loses its lock (no renewal for a whole lease: a stalled host) gets a LockError on exit.
        """
        lock = LeasedLock(self.fs, self._marker(stage, key, ".lock"), self.local, label, lease_s)
        self.fs.makedirs(self.version_dir(stage, key), exist_ok=True)
        lock.acquire()
        try:
            yield
        finally:
            lock.release()
        if lock.lost:
            raise LockError(f"partition {label}: another run took over {lock.path} while this one held it (no "
                            f"renewal for {lock.me['lease_s']:g} s: a stalled host or storage); the other run "
                            f"rewrites the partition; if it failed, run again")


def init_zarr(target: str, schema: ArtifactSchema, ds: xr.Dataset, n_frames: int, with_data: bool = False,
              digests: dict[str, str] | None = None) -> None:
    """Create a zarr v3 group shaped like ``ds`` but ``n_frames`` long: metadata and frame-less arrays only.

    ``with_data``: ``ds`` already holds all ``n_frames`` frames; write everything in one pass. ``digests``: filled
    with the digest of every chunk written (pipeline/integrity.py).
    """
    target = _writer(target, digests)
    if with_data:
        encoding = {name: {"chunks": schema.chunks(name, var.shape, var.dims), **_codec(var)}
                    for name, var in ds.data_vars.items() if "frame" in var.dims}
        whole = xr.Dataset({n: _variable_strings(v.variable) for n, v in ds.data_vars.items()},
                           coords={n: _variable_strings(c.variable) for n, c in ds.coords.items()}, attrs=ds.attrs)
        whole.to_zarr(target, mode="w", zarr_format=3, consolidated=False, encoding=encoding, write_empty_chunks=True)
    else:
        template, encoding = _template(schema, ds, n_frames)
        template.to_zarr(target, mode="w", compute=False, zarr_format=3, consolidated=False, encoding=encoding,
                         write_empty_chunks=True)


def write_zarr_region(target: str, ds: xr.Dataset, start: int, stop: int, digests: dict[str, str] | None = None) -> None:
    """Write the frame-dimensioned variables of ``ds`` into frames [start, stop) of an initialized group
    (``digests``: filled with the digest of every chunk written, pipeline/integrity.py).

    Every array in one pass of zarr's event loop: their metadata read and their chunks written concurrently.
    xarray's region write (which this replaces) takes a round trip through that loop per array and per
    metadata file, and each round trip waits for the GIL while the other worker threads compute: 60 ms for
    the few bytes of a reflectors2d region, against 14 ms alone. The stored chunks are the same bytes: the
    schemas' dtypes are exact and xarray's encoding of them is the identity.

    No public zarr API runs a coroutine on zarr's own loop, so this uses zarr's internal ``zarr.core.sync.sync``;
    zarr's public per-array API writes the same bytes but took 1.4 to 1.6 times as long while another thread
    computed, and 1.1 to 1.2 times alone (benchmarks/region_write.py, zarr 3.1.6). ``ZARR_RANGE`` (pinned in
    pyproject.toml and checked by tests/pipeline/test_storage.py) is the zarr releases this is tested on.
    """
    framed = {name: var for name, var in ds.variables.items() if "frame" in var.dims}
    if framed:
        _zarr_sync()(_write_arrays(_writer(target, digests), framed, start, stop, target))


def _zarr_sync():
    """zarr's internal ``sync`` (runs a coroutine on zarr's event loop), or a StorageError naming the zarr installed."""
    try:
        from zarr.core.sync import sync
    except ImportError as exc:
        import zarr

        raise StorageError(f"zarr {zarr.__version__} has no zarr.core.sync.sync, which region writes use; "
                           f"install a zarr release in the tested range: pip install 'zarr{ZARR_RANGE}'") from exc
    return sync


def _writer(target: str, digests: dict[str, str] | None):
    """``target`` itself, or a zarr store writing to it that records chunk digests in ``digests``."""
    if digests is None:
        return target

    return RecordingStore(zarr_store(target, read_only=False), digests)


async def _write_arrays(store, framed: dict, start: int, stop: int, target: str) -> None:
    """Frames [start, stop) of each of ``framed``'s variables into its zarr array (named dims, stored order) in
    ``store`` (``target``, or a store writing there)."""
    import asyncio

    import zarr.api.asynchronous as zarr_async

    group = await zarr_async.open_group(store, mode="r+", zarr_format=3)
    arrays = dict(zip(framed, await asyncio.gather(*(group.getitem(name) for name in framed))))
    for name, var in framed.items():  # every array checked before any is written
        stored = tuple(arrays[name].metadata.dimension_names or ())
        if stored != var.dims:
            raise StorageError(f"{target}: array {name!r} is stored with dims {stored}, but the region of frames "
                               f"{start}-{stop} to write has dims {var.dims}; this store was initialized with another "
                               f"layout: delete {target} (for an artifact, its version folder) and run again")

    async def one(name: str, var: xr.Variable) -> None:
        array = arrays[name].with_config({"write_empty_chunks": True})
        await array.setitem(tuple(slice(start, stop) if d == "frame" else slice(None) for d in var.dims), var.values)

    await asyncio.gather(*(one(n, v) for n, v in framed.items()))


def _codec(var: xr.DataArray | xr.Variable) -> dict:
    """The codecs of one frame-dimensioned variable, all lossless and all zstd at level 1 (zarr's default 3 took the
    whole run 5 % longer for 2 % less disk), chosen by dtype and layout (``python benchmarks/cache_size.py``):

    - integers of 2 bytes or more (the sensors' depth and IR, blob ids): Blosc's bit shuffle before zstd; the high
      bits of neighbouring counts agree, and IR takes 23 %, depth 40 % less disk in about the same write time;
    - float images with a channel after (y, x) (the 3D flow): the channels stored as planes (zarr's transpose
      codec), 8 % less disk for 1 ms more per view-frame to write;
    - the rest, 8-bit colour images included: zstd alone. Shuffles made heatmaps larger, and planes save the
      colorized flow 7 % for three times the time to read it, on the heatmaps' path.

    Only how chunks are encoded changes: readers see the same arrays, and stores written before stay readable
    (zarr reads every array's codecs from its metadata).
    """
    from zarr.codecs import BloscCodec, TransposeCodec, ZstdCodec

    dtype, dims = np.dtype(var.dtype), tuple(var.dims)
    if dtype.kind in "iu" and dtype.itemsize >= 2:
        return {"compressors": BloscCodec(cname="zstd", clevel=1, shuffle="bitshuffle", typesize=dtype.itemsize)}
    if dtype.kind == "f" and len(dims) >= 3 and dims[-3:-1] == ("y", "x"):
        planes = tuple(range(len(dims) - 3)) + (len(dims) - 1, len(dims) - 3, len(dims) - 2)  # (..., c, y, x)
        return {"filters": TransposeCodec(order=planes), "compressors": ZstdCodec(level=1)}
    return {"compressors": ZstdCodec(level=1)}


def check(schema: ArtifactSchema, ds: xr.Dataset, what: str) -> None:
    try:
        schema.validate(ds)
    except SchemaViolation as exc:
        raise SchemaError(f"{what} does not match its schema: {exc}") from exc


def _template(schema: ArtifactSchema, ds: xr.Dataset, n_frames: int) -> tuple[xr.Dataset, dict]:
    """A lazily-zero Dataset of the full frame length, and the chunk encoding from the schema."""
    import dask.array as da  # here, not at the top: about 0.3 s of every command's start, and only writers need it

    variables, encoding = {}, {}
    for name, var in ds.data_vars.items():
        if "frame" in var.dims:
            shape = tuple(n_frames if d == "frame" else s for d, s in zip(var.dims, var.shape))
            chunks = schema.chunks(name, shape, var.dims)
            variables[name] = xr.Variable(var.dims, da.zeros(shape, dtype=var.dtype, chunks=chunks), var.attrs)
            encoding[name] = {"chunks": chunks, **_codec(var)}
        else:
            variables[name] = _variable_strings(var.variable)
    coords = {name: _variable_strings(c.variable) for name, c in ds.coords.items() if "frame" not in c.dims}
    if "frame" in ds.dims:
        coords["frame"] = xr.Variable(("frame",), np.arange(n_frames, dtype=np.int64))
    return xr.Dataset(variables, coords=coords, attrs=ds.attrs), encoding


def _frames_text(frames: np.ndarray) -> str:
    """A frame coordinate for a message: all of it when short, else its ends and length."""
    values = np.asarray(frames).tolist()
    if len(values) <= 8:
        return str(values)
    return f"[{values[0]}, {values[1]}, ..., {values[-1]}] ({len(values)} frames)"


def _variable_strings(var: xr.Variable) -> xr.Variable:
    """Fixed-width unicode has no zarr v3 spec; store strings as variable-length."""
    return var.astype(object) if var.dtype.kind == "U" else var


def _region_record(data: bytes) -> dict:
    """A region or ``_init`` marker's record: ``{"seconds", "chunks"}``; older markers held the seconds alone, or
    nothing."""
    try:
        record = json.loads(data or b"{}")
    except ValueError:
        return {}
    if isinstance(record, (int, float)):
        return {"seconds": float(record)}
    return record if isinstance(record, dict) else {}


def _chunk_groups(recorded: dict) -> dict[str, dict[str, str]]:
    """``"init"``, each region and ``"meta"`` (the metadata, recorded at the commit) -> {zarr key: digest}, from
    ``Store.digests``."""
    return {"init": recorded.get("init", {}), **recorded.get("regions", {}), "meta": recorded.get("meta", {})}


def _storage_options(root: str) -> dict:
    """The fsspec options of a storage root: none for a local folder; for any other (an object store) no listings
    cache, since other processes and hosts write there meanwhile and every check of a marker, a lock or a run lease
    must see their writes (s3fs answers ``exists`` from a cached listing of the folder otherwise). Credentials and
    endpoints come from the environment or fsspec's configuration, never from the catalog (docs/engine.md, Object
    stores)."""
    protocol = fsspec.core.split_protocol(root)[0]
    return {} if protocol in (None, "file", "local") else {"use_listings_cache": False}


def _protocols(fs) -> tuple[str, ...]:
    proto = fs.protocol
    return (proto,) if isinstance(proto, str) else tuple(proto)

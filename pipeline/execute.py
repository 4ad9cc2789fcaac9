"""Worker side: produce one partition, region by region, under its lock.

One runner for every stage: load the inputs of a frame region (plus the task's halo) from
storage, call the pure task with the stage's params as keyword arguments, crop the halo, check
the schema, write the region, commit its marker. Regions already committed are skipped once their
chunks match their digests, so a killed run resumes where it stopped and a damaged region is written again.

A *unit* runs one frame region of a group of partitions that work region by region: the stages of
one sequence x view (say masks -> flow -> heatmaps -> reflectors2d), or of one sequence. Each
member's output is written as usual and handed to the members after it in memory (with the last
frames of the group's previous region, for a halo), and an input several members read (the raw
frames) is loaded once. The artifacts are the same as partition by partition.
"""

from __future__ import annotations

import logging
import os
import socket
import time
import traceback
import warnings
from contextlib import contextmanager, nullcontext
from dataclasses import dataclass
from typing import Iterator

import xarray as xr

from mocapflow.pipeline import registry
from mocapflow.pipeline.checkpoints import Checkpoint
from mocapflow.pipeline.datasets import read_frames
from mocapflow.pipeline.errors import InputWarning, MocapflowError, StorageError
from mocapflow.pipeline.locks import no_space
from mocapflow.pipeline.models import load_weights
from mocapflow.pipeline.plan import WorkItem, now
from mocapflow.pipeline.samples import samples_input, select_variables
from mocapflow.pipeline.storage import Store
from mocapflow.tasks.shared.cache import BoundedCache

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Result:
    partition: str
    status: str  # executed | cached | failed | skipped
    error: str = ""
    detail: str = ""
    seconds: float = 0.0
    regions: int = 0
    warnings: tuple[str, ...] = ()  # InputWarnings raised while computing it (a reader's, a task's)

    @property
    def ok(self) -> bool:
        return self.status in ("executed", "cached")


def regions(n_frames: int, region_frames: int, frame_chunk: int) -> list[tuple[int, int]]:
    """Frame regions aligned to the schema's frame chunks (a region is a whole number of chunks)."""
    size = max(frame_chunk, (region_frames // frame_chunk) * frame_chunk)
    return [(a, min(a + size, n_frames)) for a in range(0, n_frames, size)]


def spans(item: WorkItem) -> list[tuple[int, int]]:
    """The frame regions ``item`` is produced in (one for a whole-sequence task)."""
    n = item.sequence.n_frames
    return [(0, n)] if item.spec.whole_sequence else regions(n, item.stage.region_frames, item.stage.schema.frame_chunk)


def failed_upstream(item: WorkItem, upstream) -> list[str]:
    """The partitions ``item`` reads whose Result (among ``upstream``: Results or lists of them) is not ok."""
    reads = set(item.depends_on)
    return sorted({r.partition for r in _flat(upstream) if not r.ok and r.partition in reads})


def _flat(upstream) -> list[Result]:
    return [r for u in upstream for r in (u if isinstance(u, (list, tuple)) else [u])]


def run_partition(item: WorkItem, *upstream) -> Result:
    """Produce ``item`` unless it is complete; failures come back as a Result, never raised."""
    failed_up = failed_upstream(item, upstream)
    if failed_up:
        return Result(item.partition.id, "skipped", error=f"upstream failed: {', '.join(failed_up)}")
    store = Store(item.root)
    return _locked(item, store, lambda started: (_produce(item, store), True))


def _locked(item: WorkItem, store: Store, produce) -> Result:
    """Run ``produce(started) -> (regions written, changed)`` under ``item``'s lock unless its partition is
    complete (before or once the lock is held): "cached", or "executed" when something changed; failures
    come back as a Result, never raised."""
    pid, stage, key = item.partition.id, item.partition.stage, item.key
    started = time.perf_counter()
    try:
        registry.import_plugins(item.plugins)
        if store.is_complete(stage, key):
            return Result(pid, "cached")
        with store.lock(stage, key, pid), warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always", InputWarning)
            if store.is_complete(stage, key):
                return Result(pid, "cached")
            written, changed = produce(started)
        said = tuple(dict.fromkeys(str(w.message) for w in caught if issubclass(w.category, InputWarning)))
        return Result(pid, "executed" if changed else "cached", seconds=time.perf_counter() - started,
                      regions=written, warnings=said)
    except MocapflowError as exc:
        return Result(pid, "failed", error=str(exc), seconds=time.perf_counter() - started)
    except OSError as exc:
        if no_space(exc):
            return Result(pid, "failed", error=f"storage root {item.root} is full ({exc.strerror}): partition {pid} "
                          "was not written; free space there (or point storage.root elsewhere) and run again; "
                          "the written regions are kept", seconds=time.perf_counter() - started)
        return Result(pid, "failed", error=f"{type(exc).__name__}: {exc}", detail=traceback.format_exc(),
                      seconds=time.perf_counter() - started)
    except Exception as exc:  # a task's own bug: report it with its traceback, keep the run alive
        return Result(pid, "failed", error=f"{type(exc).__name__}: {exc}", detail=traceback.format_exc(),
                      seconds=time.perf_counter() - started)


@dataclass(frozen=True)
class Unit:
    """Frames [start, stop) of a group of partitions (``items``, upstream first) of one sequence x view or one
    sequence, run in one task; ``first`` / ``last``: the group's first / last region."""

    items: tuple[WorkItem, ...]
    start: int
    stop: int
    first: bool
    last: bool

    @property
    def id(self) -> str:
        head = self.items[0].partition
        where = "/".join(p for p in (head.sequence, head.view) if p is not None)
        return f"{'+'.join(i.partition.stage for i in self.items)}/{where}@{self.start}-{self.stop}"


def run_unit(unit: Unit, *upstream) -> list[Result]:
    """Produce frames [start, stop) of every member of ``unit`` not yet written, each member's output going to
    the members after it in memory; one Result per member (in order), failures reported, never raised. A
    member whose input failed (here or in an earlier region) is skipped; the others go on."""
    store = Store(unit.items[0].root)
    loader = _UnitInputs(store, unit)
    before = _flat(upstream)  # the upstream units' reports, this group's previous region included
    done: list[Result] = []
    for item in unit.items:
        pid = item.partition.id
        failed_up = failed_upstream(item, before + done)
        if any(r.partition == pid and not r.ok for r in before):
            done.append(Result(pid, "skipped", error="an earlier region of this partition failed"))
        elif failed_up:
            done.append(Result(pid, "skipped", error=f"upstream failed: {', '.join(failed_up)}"))
        else:
            done.append(_unit_member(item, unit, store, loader))
    return done


def _unit_member(item: WorkItem, unit: Unit, store: Store, loader: "_UnitInputs") -> Result:
    """One member's region of a unit: computed and written under the member's lock, the partition committed
    after the group's last region."""
    stage, key = item.partition.stage, item.key

    def produce(started: float) -> tuple[int, bool]:
        written = 0
        if not store.resume_region(stage, key, unit.start, unit.stop):
            cpu = time.process_time()
            if unit.first or not store.pending_lineage(stage, key):
                store.begin(stage, key, item.lineage(started=now(), host=socket.gethostname()))
            out = _compute_region(item, store, unit.start, unit.stop, load=loader.for_member(item))
            store.write_region(stage, key, item.stage.schema, out, item.sequence.n_frames, unit.start,
                               unit.stop, seconds=time.perf_counter() - started,
                               cpu_seconds=time.process_time() - cpu)
            loader.keep(item, out)
            written = 1
        if unit.last and not _commit_if_whole(item, store):
            raise StorageError(_uncommitted(item, store))
        return written, bool(written or unit.last)

    return _locked(item, store, produce)


def _commit_if_whole(item: WorkItem, store: Store) -> bool:
    """Commit ``item``'s partition if every region is written (lineage: its start, and the sum of the regions'
    seconds, earlier runs' included)."""
    stage, key = item.partition.stage, item.key
    if not all(store.region_done(stage, key, a, b) for a, b in spans(item)):
        return False
    begun = store.pending_lineage(stage, key)
    store.commit(stage, key, item.lineage(started=begun.get("started", now()), finished=now(),
                                          host=socket.gethostname(),
                                          compute_seconds=round(store.region_seconds(stage, key), 3),
                                          code_version=item.spec.version, schema=item.components["schema"]))
    return True


class _UnitInputs:
    """Inputs of a unit's members: the output of an earlier member of this region from memory (earlier frames
    of a halo from storage), anything else from storage, each upstream artifact loaded once for the unit
    (every variable and frame its readers in the unit need)."""

    def __init__(self, store: Store, unit: Unit):
        self.store, self.unit = store, unit
        self.memory: dict[str, xr.Dataset] = {}
        self.loaded: dict[tuple, xr.Dataset] = {}
        self.wanted: dict[tuple, tuple] = {}  # upstream -> (variables or None for all, lo, hi)
        members = {i.partition.stage for i in unit.items}
        self.halos: dict[str, int] = {}  # member -> the most frames before a region that a member reads of it
        for item in unit.items:
            spec = item.spec
            lo, hi = max(0, unit.start - spec.halo[0]), min(item.sequence.n_frames, unit.stop + spec.halo[1])
            for role, up in item.upstream.items():
                if up.stage in members:
                    self.halos[up.stage] = max(self.halos.get(up.stage, 0), spec.halo[0])
                    continue
                source = _upstream_id(up)
                names, a, b = self.wanted.get(source, ((), lo, hi))
                reads = spec.reads.get(role)
                names = None if names is None or reads is None else tuple(dict.fromkeys(names + tuple(reads)))
                self.wanted[source] = (names, min(a, lo), max(b, hi))
        # the previous region's last frames, before this unit replaces them
        self.tails = {i.partition.stage: _TAILS.get((i.partition.stage, i.key)) for i in unit.items}

    def keep(self, item: WorkItem, out: xr.Dataset) -> None:
        """``item``'s output of this region, for the members after it; its last frames also for the group's next
        region (a halo), if that runs in this process."""
        self.memory[item.partition.stage] = out
        halo = self.halos.get(item.partition.stage, 0)
        if halo and not self.unit.last and "frame" in out.dims:
            _TAILS.put((item.partition.stage, item.key), out.isel(frame=slice(-halo, None)))

    def for_member(self, item: WorkItem):
        view = item.partition.view

        def load(up, lo, hi, variables):
            if up.stage in self.memory:
                return self._from_memory(up, view, lo, hi, variables)
            source = _upstream_id(up)
            if source not in self.wanted:  # a member that found this region written: from storage
                return _load_input(self.store, up, view, lo, hi, variables, partial=True)
            if source not in self.loaded:
                names, a, b = self.wanted[source]
                self.loaded[source] = _load_input(self.store, up, view, a, b, names, partial=True)
            ds = select_variables(self.loaded[source], variables, up)
            return ds.sel(frame=slice(lo, hi - 1)) if "frame" in ds.dims else ds

        return load

    def _from_memory(self, up, view, lo: int, hi: int, variables) -> xr.Dataset:
        ds = select_variables(self.memory[up.stage], variables, up)
        assert hi <= self.unit.stop, (up.stage, hi, self.unit.stop)  # groups hold no look-ahead halo
        if lo >= self.unit.start:
            return ds.sel(frame=slice(lo, hi - 1))
        tail = self.tails.get(up.stage)
        if tail is not None and tail["frame"].size and int(tail["frame"][0]) <= lo and \
                int(tail["frame"][-1]) == self.unit.start - 1:
            earlier = select_variables(tail, variables, up)
            earlier = earlier.sel(frame=slice(lo, self.unit.start - 1))
        else:
            earlier = _load_input(self.store, up, view, lo, self.unit.start, variables, partial=True)
        return xr.concat([earlier, ds], dim="frame", data_vars="minimal", coords="minimal", compat="override",
                         join="override")


_TAILS: BoundedCache[tuple[str, str], xr.Dataset] = BoundedCache(32)  # (stage, key) -> its latest region's last frames


def _upstream_id(up) -> tuple:
    return (up.stage, tuple(sorted((str(k), v) for k, v in up.keys.items())))


def _produce(item: WorkItem, store: Store) -> int:
    schema = item.stage.schema
    stage, key = item.partition.stage, item.key
    store.begin(stage, key, item.lineage(started=now(), host=socket.gethostname()))
    written = 0
    for start, stop in spans(item):
        if store.resume_region(stage, key, start, stop):
            continue
        t0, cpu = time.perf_counter(), time.process_time()
        out = _compute_region(item, store, start, stop)
        store.write_region(stage, key, schema, out, item.sequence.n_frames, start, stop,
                           seconds=time.perf_counter() - t0, cpu_seconds=time.process_time() - cpu)
        written += 1
        log.debug("%s: frames %d-%d written", item.partition.id, start, stop)
    if not _commit_if_whole(item, store):
        raise StorageError(_uncommitted(item, store))
    return written


def _uncommitted(item: WorkItem, store: Store) -> str:
    """Why ``item``'s partition could not be committed after its last region: the regions missing."""
    stage, key = item.partition.stage, item.key
    missing = [f"{a}-{b}" for a, b in spans(item) if not store.region_done(stage, key, a, b)]
    return (f"partition {item.partition.id} was not committed: frames {', '.join(missing[:4])}"
            f"{' ...' if len(missing) > 4 else ''} of {store.version_dir(stage, key)} are missing after its last "
            f"region was written (another process deleted them meanwhile); run again to write them")


def _compute_region(item: WorkItem, store: Store, start: int, stop: int, load=None) -> xr.Dataset:
    """``item``'s task on frames [start, stop); ``load(up, lo, hi, variables)`` gives an input (from storage
    when None)."""
    spec = item.spec
    if spec.source:
        return read_frames(item.dataset, item.sequence, start, stop)
    if spec.partition == "dataset":
        inputs = {role: samples_input(store, up, spec.reads.get(role), spec.streams.get(role, ()))
                  for role, up in item.upstream.items()}
    else:
        lo = max(0, start - spec.halo[0])
        hi = min(item.sequence.n_frames, stop + spec.halo[1])
        if load is None:
            def load(up, lo, hi, variables):
                return _load_input(store, up, item.partition.view, lo, hi, variables)
        inputs = {role: load(up, lo, hi, spec.reads.get(role)) for role, up in item.upstream.items()}
    weights = {name: load_weights(path, sha) for name, (path, sha) in item.weights.items()}  # cached per worker
    if spec.checkpoints:
        weights["checkpoint"] = Checkpoint(store, item.partition.stage, item.key)
    with every_core() if spec.partition == "dataset" else nullcontext():
        out = spec.fn(**inputs, config=item.stage.params, **weights)
    if not isinstance(out, xr.Dataset):
        raise TypeError(f"task {spec.name!r} returned {type(out).__name__}, expected an xarray Dataset")
    if "frame" in out.dims:
        out = out.sel(frame=slice(start, stop - 1))
    return out


@contextmanager
def every_core() -> Iterator[None]:
    """torch and OpenCV on every core of the machine for the duration. A per-dataset task (training) reads every
    partition of its inputs, so it runs after them, alone; a worker process's thread pools otherwise hold its
    share of the cores (scheduler.thread_limits)."""
    import cv2
    import torch

    before = torch.get_num_threads(), cv2.getNumThreads()
    cores = os.cpu_count() or 1
    torch.set_num_threads(cores)
    cv2.setNumThreads(cores)
    try:
        yield
    finally:
        torch.set_num_threads(before[0])
        cv2.setNumThreads(before[1])


def _load_input(store: Store, up, view: str | None, lo: int, hi: int, variables=None,
                partial: bool = False) -> xr.Dataset:
    """Upstream artifact for this partition's view(s) and frames [lo, hi) (only ``variables``), in memory.
    ``partial``: the artifact may be incomplete (the caller knows those frames are written)."""
    parts = []
    for key in up.keys.values():
        ds = store.open(up.stage, key, up.schema, partial=partial)
        ds = select_variables(ds, variables, up)
        if up.partition == "sequence" and view is not None and "view" in ds.dims:  # a slice: zarr reads it 3x faster
            at = [str(v) for v in ds["view"].values].index(str(view))
            ds = ds.isel(view=slice(at, at + 1))
        if "frame" in ds.dims:
            ds = ds.isel(frame=slice(lo, hi))
        parts.append(ds)
    merged = parts[0] if len(parts) == 1 else xr.concat(parts, dim="view", data_vars="minimal",
                                                        coords="minimal", compat="override", join="override")
    return merged.load()

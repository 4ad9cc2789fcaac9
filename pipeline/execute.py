"""Worker side: produce one partition, region by region, under its lock.

One runner for every stage: load the inputs of a frame region (plus the task's halo) from
storage, call the pure task with the stage's params as keyword arguments, crop the halo, check
the schema, write the region, commit its marker. Regions already committed are skipped, so a
killed run resumes where it stopped.
"""

from __future__ import annotations

import logging
import socket
import time
import traceback
from dataclasses import dataclass, fields

import numpy as np
import xarray as xr

from mocapflow.pipeline import registry
from mocapflow.pipeline.datasets import read_frames
from mocapflow.pipeline.errors import MocapflowError
from mocapflow.pipeline.models import load_weights
from mocapflow.pipeline.plan import WorkItem, now
from mocapflow.pipeline.storage import Store
from mocapflow.schemas import get_schema

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Result:
    partition: str
    status: str  # executed | cached | failed | skipped
    error: str = ""
    detail: str = ""
    seconds: float = 0.0
    regions: int = 0

    @property
    def ok(self) -> bool:
        return self.status in ("executed", "cached")


def regions(n_frames: int, region_frames: int, frame_chunk: int) -> list[tuple[int, int]]:
    """Frame regions aligned to the schema's frame chunks (a region is a whole number of chunks)."""
    size = max(frame_chunk, (region_frames // frame_chunk) * frame_chunk)
    return [(a, min(a + size, n_frames)) for a in range(0, n_frames, size)]


def run_partition(item: WorkItem, *upstream: Result) -> Result:
    """Produce ``item`` unless it is complete; failures come back as a Result, never raised."""
    pid = item.partition.id
    failed_up = [r.partition for r in upstream if not r.ok]
    if failed_up:
        return Result(pid, "skipped", error=f"upstream failed: {', '.join(failed_up)}")
    started = time.perf_counter()
    try:
        registry.import_plugins(item.catalog.plugins)
        store = Store(item.catalog.root)
        if store.is_complete(item.partition.stage, item.key):
            return Result(pid, "cached")
        with store.lock(item.partition.stage, item.key, pid):
            if store.is_complete(item.partition.stage, item.key):
                return Result(pid, "cached")
            written = _produce(item, store)
        return Result(pid, "executed", seconds=time.perf_counter() - started, regions=written)
    except MocapflowError as exc:
        return Result(pid, "failed", error=str(exc), seconds=time.perf_counter() - started)
    except Exception as exc:  # a task's own bug: report it with its traceback, keep the run alive
        return Result(pid, "failed", error=f"{type(exc).__name__}: {exc}", detail=traceback.format_exc(),
                      seconds=time.perf_counter() - started)


def _produce(item: WorkItem, store: Store) -> int:
    spec = registry.get(item.stage.task)
    schema = get_schema(spec.output)
    stage, key = item.partition.stage, item.key
    started = now()
    store.begin(stage, key, item.lineage(started=started, host=socket.gethostname()))
    n = item.sequence.n_frames
    written = 0
    t0 = time.perf_counter()
    spans = [(0, n)] if spec.whole_sequence else regions(n, item.stage.region_frames, schema.frame_chunk)
    for start, stop in spans:
        if store.region_done(stage, key, start, stop):
            continue
        out = _compute_region(item, spec, store, start, stop)
        store.write_region(stage, key, schema, out, n, start, stop)
        written += 1
        log.debug("%s: frames %d-%d written", item.partition.id, start, stop)
    store.commit(stage, key, item.lineage(started=started, finished=now(), host=socket.gethostname(),
                                          compute_seconds=round(time.perf_counter() - t0, 3),
                                          code_version=spec.version, schema=item.components["schema"]))
    return written


def _compute_region(item: WorkItem, spec: registry.TaskSpec, store: Store, start: int, stop: int) -> xr.Dataset:
    if spec.source:
        dataset = item.catalog.datasets[item.stage.dataset]
        return read_frames(item.catalog, dataset, item.sequence, start, stop)
    if spec.partition == "dataset":
        inputs = {role: _load_samples(store, up, spec.reads.get(role)) for role, up in item.upstream.items()}
    else:
        lo = max(0, start - spec.halo[0])
        hi = min(item.sequence.n_frames, stop + spec.halo[1])
        inputs = {role: _load_input(store, up, item.partition.view, lo, hi, spec.reads.get(role))
                  for role, up in item.upstream.items()}
    params = {f.name: getattr(item.stage.params, f.name) for f in fields(item.stage.params)}
    for name, (path, sha) in item.weights.items():  # weight files arrive as tensors, loaded once per worker
        params[name] = load_weights(path, sha)
    out = spec.fn(**inputs, **params)
    if not isinstance(out, xr.Dataset):
        raise TypeError(f"task {spec.name!r} returned {type(out).__name__}, expected an xarray Dataset")
    if "frame" in out.dims:
        out = out.sel(frame=slice(start, stop - 1))
    return out


def _load_samples(store: Store, up, variables=None) -> xr.Dataset:
    """A per-dataset stage's input: every (sequence, view, frame) of the upstream as one ``sample`` dim.

    Each sample carries ``sequence``, ``view`` and ``frame`` coordinates; variables without a frame
    dimension (calibration, say) are left out, since samples of different sequences cannot share them.
    """
    parts = []
    for sequence, keys in up.by_sequence.items():
        for key in keys.values():
            ds = store.open(up.stage, key, get_schema(up.schema))
            ds = ds[list(variables)] if variables is not None else ds
            ds = ds.drop_vars([n for n, v in ds.data_vars.items() if "frame" not in v.dims])
            stacked = ds.stack(sample=[d for d in ("view", "frame") if d in ds.dims]).transpose("sample", ...).load()
            stacked = stacked.reset_index("sample").assign_coords(
                sequence=("sample", np.full(stacked.sizes["sample"], sequence, dtype=object)))
            parts.append(stacked)
    return xr.concat(parts, dim="sample", data_vars="minimal", coords="minimal", compat="override", join="override")


def _load_input(store: Store, up, view: str | None, lo: int, hi: int, variables=None) -> xr.Dataset:
    """Upstream artifact for this partition's view(s) and frames [lo, hi) (only ``variables``), in memory."""
    parts = []
    for key in up.keys.values():
        ds = store.open(up.stage, key, get_schema(up.schema))
        if variables is not None:
            ds = ds[list(variables)]
        if up.partition == "sequence" and view is not None:
            ds = ds.sel(view=[view])
        if "frame" in ds.dims:
            ds = ds.isel(frame=slice(lo, hi))
        parts.append(ds)
    merged = parts[0] if len(parts) == 1 else xr.concat(parts, dim="view", data_vars="minimal",
                                                        coords="minimal", compat="override", join="override")
    return merged.load()

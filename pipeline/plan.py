"""Planning: partitions, cache keys and their status.

Per-view stages partition by sequence x view, per-sequence stages by sequence, per-dataset stages
(training, say) have one partition reading every sequence of their dataset. The cache key
of a partition hashes everything its output depends on: stage name, implementation and its
explicit code version, canonical params, output schema version, upstream keys, the raw input's
fingerprint (source stages) and the hash of any weight file a param names.
"""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass, field
from typing import Any, Mapping

import numpy as np
import xarray as xr

from mocapflow.pipeline import registry
from mocapflow.pipeline.catalog import Catalog, DatasetConfig, StageConfig
from mocapflow.pipeline.datasets import SequenceInfo, discover
from mocapflow.pipeline.errors import PlanError
from mocapflow.pipeline.hashing import digest, file_digest
from mocapflow.pipeline.storage import Store
from mocapflow.models import packaged
from mocapflow.schemas import ArtifactSchema


@dataclass(frozen=True)
class Partition:
    stage: str
    sequence: str
    view: str | None = None

    @property
    def id(self) -> str:
        return "/".join(p for p in (self.stage, self.sequence, self.view) if p is not None)


@dataclass(frozen=True)
class Upstream:
    """One input role of a work item: the upstream stage and the keys it reads (one per view or one)."""

    stage: str
    partition: str  # "view" or "sequence"
    schema: ArtifactSchema
    keys: Mapping[str | None, str]  # view (or None) -> key
    by_sequence: Mapping[str, Mapping[str | None, str]] | None = None  # a per-dataset reader: sequence -> keys


@dataclass(frozen=True)
class WorkItem:
    """Everything a worker needs to produce one partition, and no more: its stage (resolved spec, schema and
    params), the storage root, the plugins to import, and for a source stage its dataset."""

    partition: Partition
    key: str
    components: Mapping[str, Any]
    upstream: Mapping[str, Upstream]
    sequence: SequenceInfo
    stage: StageConfig
    root: str
    plugins: tuple[str, ...] = ()
    dataset: DatasetConfig | None = None  # source stages: where their sequences come from
    weights: Mapping[str, tuple[str, str]] = field(default_factory=dict)  # param -> (path, sha256)

    @property
    def spec(self) -> registry.TaskSpec:
        return self.stage.spec

    @property
    def depends_on(self) -> list[str]:
        out = []
        for up in self.upstream.values():
            for sequence, keys in (up.by_sequence or {self.partition.sequence: up.keys}).items():
                out.extend(Partition(up.stage, sequence, view).id for view in keys)
        return out

    def lineage(self, **extra) -> dict:
        return {"partition": self.partition.id, "key": self.key, "components": dict(self.components), **extra}


@dataclass
class Plan:
    items: dict[str, WorkItem] = field(default_factory=dict)  # partition id -> item, topological
    sequences: list[SequenceInfo] = field(default_factory=list)
    dataset_of: dict[str, str] = field(default_factory=dict)  # sequence id -> dataset name

    def for_stages(self, stages: list[str]) -> list[WorkItem]:
        return [i for i in self.items.values() if i.partition.stage in stages]

    def by_stage(self) -> dict[str, list[WorkItem]]:
        """Every stage's work items, in plan order."""
        grouped: dict[str, list[WorkItem]] = {}
        for item in self.items.values():
            grouped.setdefault(item.partition.stage, []).append(item)
        return grouped

    def item(self, stage: str, sequence: str, view: str | None = None) -> WorkItem:
        """The work item of ``stage`` for ``sequence`` (and ``view``, for a per-view stage)."""
        pid = Partition(stage, sequence, view).id
        try:
            return self.items[pid]
        except KeyError:
            raise PlanError(f"no partition {pid!r} in the plan{registry.did_you_mean(pid, self.items)}; "
                            "check the stage, sequence and view names (`mocapflow status` lists them)") from None

    def open(self, store: Store, stage: str, sequence: str, view: str | None = None) -> xr.Dataset:
        """The stored artifact of ``stage`` for ``sequence`` (and ``view``), lazily, checked against its schema."""
        item = self.item(stage, sequence, view)
        return store.open(stage, item.key, item.stage.schema)


def build_plan(catalog: Catalog, sequences: str | None = None) -> Plan:
    """Keys for every stage x partition of the catalog (for the sequences matching the glob)."""
    plan = Plan()
    seqs_by_dataset = _discover_all(catalog, sequences)
    source_of = _source_datasets(catalog)
    weights = {stage.name: _weights(catalog, stage) for stage in catalog.stages.values()}
    for dataset_name, seqs in seqs_by_dataset.items():
        plan.sequences.extend(seqs)
        plan.dataset_of.update({seq.id: dataset_name for seq in seqs})
        stages = [s for s in catalog.stages.values() if source_of[s.name] == dataset_name]
        per_dataset = [s for s in stages if s.spec.partition == "dataset"]
        all_keys: dict[str, dict[str, dict[str | None, str]]] = {}  # sequence -> stage -> view -> key
        for seq in seqs:
            keys: dict[str, dict[str | None, str]] = all_keys.setdefault(seq.id, {})
            for stage in stages:
                if stage in per_dataset:
                    continue
                views = list(seq.views) if stage.spec.partition == "view" else [None]
                keys[stage.name] = {}
                for view in views:
                    item = _work_item(catalog, stage, seq, view, keys, weights[stage.name])
                    keys[stage.name][view] = item.key
                    plan.items[item.partition.id] = item
        for stage in per_dataset:
            item = _dataset_item(catalog, stage, dataset_name, seqs, all_keys, weights[stage.name])
            plan.items[item.partition.id] = item
    check_ceiling(plan, catalog.max_partition_bytes)
    return plan


BYTES_PER_VALUE = 4  # float32, the widest per-pixel value the image stages hold


def check_ceiling(plan: Plan, ceiling: int) -> None:
    """PlanError naming the biggest partition when it would allocate more than ``ceiling`` bytes
    (storage.max_partition_bytes), before any worker starts."""
    sequences = {seq.id: seq for seq in plan.sequences}
    sizes = [(partition_bytes(item, sequences), n, item) for n, item in enumerate(plan.items.values())]
    if sizes:
        need, _, item = max(sizes, key=lambda s: (s[0], -s[1]))
        if need > ceiling:
            over = sum(1 for size, _, _ in sizes if size > ceiling)
            raise PlanError(f"partition {item.partition.id} (the biggest of {over} over the ceiling) would hold about "
                            f"{need} bytes ({need / 2**30:.1f} GiB: "
                            f"frames x views x {'image size' if _images(item) else 'values'} x {BYTES_PER_VALUE} B), over "
                            f"the ceiling of {ceiling} bytes (storage.max_partition_bytes); shorten the sequence, or "
                            f"raise the ceiling in the catalog's storage section or with --set "
                            f"storage.max_partition_bytes={need}")


def partition_bytes(item: WorkItem, sequences: Mapping[str, SequenceInfo]) -> int:
    """What ``item`` holds at once, estimated: the frames it holds (a region and its halo, or the whole sequence for
    a whole-sequence task, every sequence for a per-dataset one) x its views x the image size (1 where none of its
    artifacts is an image) x ``BYTES_PER_VALUE``."""
    spec, seq = item.spec, item.sequence
    images = _images(item)
    if spec.partition == "dataset":
        members = [sequences[s] for s in seq.spec.get("sequences", []) if s in sequences]
        return sum(s.n_frames * max(1, len(s.views)) * (int(np.prod(_image_size(s))) if images else 1)
                   for s in members) * BYTES_PER_VALUE
    pixels = int(np.prod(_image_size(seq))) if images else 1
    frames = seq.n_frames if spec.whole_sequence else min(seq.n_frames, item.stage.region_frames + sum(spec.halo))
    views = 1 if item.partition.view is not None else max(1, len(seq.views))
    return frames * views * pixels * BYTES_PER_VALUE


def _images(item: WorkItem) -> bool:
    """Whether ``item`` writes or reads an image (an array with y and x dims)."""
    schemas = [item.stage.schema, *(up.schema for up in item.upstream.values())]
    return any("y" in var.dims and "x" in var.dims for schema in schemas for var in schema.variables.values())


def _image_size(seq: SequenceInfo) -> tuple[int, int]:
    """(height, width) as the sequence's reader states them (``SequenceInfo.image``); (1, 1) where it states none:
    the sequence holds no images (a schema may allow an image the sequence lacks, as a marker take's video)."""
    if seq.image is None:
        return 1, 1
    height, width = seq.image
    if not (isinstance(height, int) and isinstance(width, int) and height > 0 and width > 0):
        raise PlanError(f"sequence {seq.id!r}: image size {seq.image!r} is not two positive integers "
                        "(height, width); fix its reader")
    return height, width


def _discover_all(catalog: Catalog, sequences: str | None) -> dict[str, list[SequenceInfo]]:
    """Every dataset's sequences matching ``sequences``; a glob matching none, or one id in two datasets, is refused."""
    found = {name: discover(catalog, ds, sequences) for name, ds in catalog.datasets.items()}
    if sequences and catalog.datasets and not any(found.values()):
        every = sorted(s.id for name, ds in catalog.datasets.items() for s in discover(catalog, ds))
        raise PlanError(f"--sequences {sequences!r} matches none of the catalog's sequences "
                        f"{every[:20]}{' ...' if len(every) > 20 else ''}; give a glob matching their ids, e.g. "
                        f"{every[0] + '*' if every else 'take*'!r}")
    owner: dict[str, str] = {}
    for name, seqs in found.items():
        for seq in seqs:
            if seq.id in owner:
                raise PlanError(f"sequence id {seq.id!r} is in both datasets {owner[seq.id]!r} and {name!r}; partitions "
                                "are named by sequence, so rename one of them")
            owner[seq.id] = name
    return found


def _dataset_item(catalog, stage, dataset_name, seqs, all_keys, weights) -> WorkItem:
    """The one partition of a per-dataset stage: it reads its inputs for every sequence of the dataset."""
    for up_name in stage.inputs.values():
        if catalog.stages[up_name].spec.partition == "dataset":
            raise PlanError(f"stage {stage.name!r} (per dataset) reads {up_name!r}, also per dataset; "
                            "a per-dataset stage reads per-view or per-sequence stages")
    whole = SequenceInfo(id=dataset_name, views=(), n_frames=1,
                         fingerprint=digest([s.fingerprint for s in seqs]), spec={"sequences": [s.id for s in seqs]})
    upstream = {}
    for role, up_name in stage.inputs.items():
        up = catalog.stages[up_name]
        by_sequence = {seq.id: dict(all_keys[seq.id][up_name]) for seq in seqs}
        upstream[role] = Upstream(up_name, up.spec.partition, up.schema, {}, by_sequence)
    return _item(catalog, stage, whole, None, upstream, weights)


def _work_item(catalog, stage, seq, view, keys, weights) -> WorkItem:
    upstream = {}
    for role, up_name in stage.inputs.items():
        up = catalog.stages[up_name]
        up_keys = keys[up_name]
        if up.spec.partition == "view" and view is not None:
            up_keys = {view: up_keys[view]}
        upstream[role] = Upstream(up_name, up.spec.partition, up.schema, dict(up_keys))
    return _item(catalog, stage, seq, view, upstream, weights)


def _item(catalog, stage, seq, view, upstream, weights) -> WorkItem:
    spec = stage.spec
    components = {
        "stage": stage.name,
        "partition": {"sequence": seq.id, "view": view},
        "task": spec.name,
        "code_version": spec.version,
        "params": cache_params(stage.params),
        "schema": f"{spec.output}@{stage.schema.version}",
        "upstream": {role: {"stage": u.stage, "keys": _keys_component(u)} for role, u in upstream.items()},
        "raw_input": seq.fingerprint if spec.source else None,
        "weights": {name: digest_ for name, (_, digest_) in weights.items()},
    }
    key = digest(components)
    dataset = catalog.datasets[stage.dataset] if spec.source else None
    return WorkItem(Partition(stage.name, seq.id, view), key, components, upstream, seq, stage, catalog.root,
                    catalog.plugins, dataset, weights)


def _keys_component(up: Upstream) -> dict:
    if up.by_sequence is not None:
        return {seq: {str(k): v for k, v in keys.items()} for seq, keys in up.by_sequence.items()}
    return {str(k): v for k, v in up.keys.items()}


def cache_params(params) -> dict:
    """A stage's params as its cache key sees them: every field but the run-time ones (``registry.runtime_fields``:
    how a task runs, not what it computes), so changing those recomputes nothing."""
    runtime = registry.runtime_fields(type(params))
    out = {}
    for f in dataclasses.fields(params):
        if f.name not in runtime:
            value = getattr(params, f.name)
            out[f.name] = cache_params(value) if dataclasses.is_dataclass(value) else value  # a nested group
    return out


def _weights(catalog, stage) -> dict[str, tuple[str, str]]:
    """param name -> (resolved path, sha256) of every weight file the stage's task uses."""
    out, spec = {}, stage.spec
    for name in spec.weights_params:
        value = getattr(stage.params, name)
        if value:
            path = catalog.resolve_data_path(str(value), f"stages.{stage.name}.params.{name}")
        elif name in spec.packaged_weights:
            path = packaged(spec.packaged_weights[name])
        else:
            continue
        if not path.is_file():
            raise PlanError(f"stages.{stage.name}.params.{name}: weights file {path} does not exist; "
                            "train it first (`mocapflow train`) or point the parameter at an existing file")
        if path.stat().st_size == 0:
            raise PlanError(f"stages.{stage.name}.params.{name}: weights file {path} is empty; train it again "
                            "(`mocapflow train`) or point the parameter at a complete weights file")
        out[name] = (str(path), file_digest(str(path)))
    return out


def _source_datasets(catalog: Catalog) -> dict[str, str]:
    """The dataset each stage ultimately reads from (through its inputs)."""
    out: dict[str, str] = {}
    for stage in catalog.stages.values():
        if stage.dataset is not None:
            out[stage.name] = stage.dataset
        else:
            found = {out[u] for u in stage.inputs.values() if u in out}
            if len(found) != 1:
                raise PlanError(f"stage {stage.name!r} must read exactly one dataset through its inputs, "
                                f"found {sorted(found) or 'none'}; give it a path to a source stage")
            out[stage.name] = found.pop()
    return out


def select(plan: Plan, catalog: Catalog, store: Store, *, only: str | None, until: str | None) -> list[WorkItem]:
    """The work items a run covers: all stages, ``--until`` and its ancestors, or ``--only`` one stage."""
    for flag, name in (("--only", only), ("--until", until)):
        if name is not None and name not in catalog.stages:
            raise PlanError(f"{flag} {name!r}: no such stage{registry.did_you_mean(name, catalog.stages)}; "
                            f"stages: {list(catalog.stages)}")
    if only is not None:
        items = plan.for_stages([only])
        missing = sorted({dep for i in items for dep in i.depends_on
                          if not store.is_complete(plan.items[dep].partition.stage, plan.items[dep].key)})
        if missing:
            raise PlanError(f"--only {only}: inputs are not computed yet: {', '.join(missing[:6])}"
                            f"{' ...' if len(missing) > 6 else ''}; run `mocapflow run --until {only}` instead")
        return items
    stages = catalog.ancestors(until) if until is not None else list(catalog.stages)
    return plan.for_stages(stages)


def status(item: WorkItem, store: Store, versions_by_stage: dict) -> str:
    """fresh (current key complete), damaged (current key, found damaged by ``mocapflow verify`` and not yet
    written again), partial (current key, some regions), stale (another version), missing."""
    stage = item.partition.stage
    if store.is_complete(stage, item.key):
        return "fresh"
    if store.is_damaged(stage, item.key):
        return "damaged"
    if store.regions_done(stage, item.key):
        return "partial"
    others = [v for v in versions_by_stage.get(stage, []) if v.partition == item.partition.id and v.key != item.key]
    return "stale" if others else "missing"


def held_versions(items: list[WorkItem]) -> list[tuple[str, str]]:
    """Every version (stage, key) that running ``items`` writes or reads, in order, each once."""
    out: dict[tuple[str, str], None] = {}
    for item in items:
        out[(item.partition.stage, item.key)] = None
        for up in item.upstream.values():
            for keys in (up.by_sequence.values() if up.by_sequence is not None else [up.keys]):
                out.update({(up.stage, key): None for key in keys.values()})
    return list(out)


def now() -> str:
    return time.strftime("%Y-%m-%dT%H:%M:%S")

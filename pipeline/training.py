"""`mocapflow train`: run a training catalog through the engine and export its weights artifact.

The catalog's per-dataset training stage (its one stage partitioned per dataset, or the stage named with ``--stage``)
produces the weights as a cached artifact (its key covers the training data, every parameter and the code version);
this module writes that artifact as a plain-tensor file for the stage that uses the network, which loads it with
``torch.load(..., weights_only=True)``. The system that declares the artifact's schema says how its tensors are
read (registry.System.weights); an artifact no system names is unpacked as packed network weights.
"""

from __future__ import annotations

import io
from pathlib import Path

from mocapflow.pipeline import registry
from mocapflow.pipeline.errors import PlanError, StorageError
from mocapflow.pipeline.plan import Plan, WorkItem
from mocapflow.pipeline.storage import Store
from mocapflow.tasks.shared.weights import unpack


def training_item(plan: Plan, catalog, stage: str | None) -> WorkItem:
    """The work item that trains the network: the named stage, else the catalog's one stage run per dataset."""
    names = [stage] if stage else [s.name for s in catalog.stages.values() if s.spec.partition == "dataset"]
    if len(names) != 1 or names[0] not in catalog.stages:
        raise PlanError(f"the catalog has {len(names)} training stages run per dataset ({names}); name one with "
                        "--stage")
    items = [i for i in plan.items.values() if i.partition.stage == names[0]]
    if len(items) != 1:
        raise PlanError(f"stage {names[0]!r} has {len(items)} partitions; a training stage is per dataset (one)")
    return items[0]


def export_weights(store: Store, item: WorkItem, out: Path) -> bytes:
    """Write the trained artifact of ``item`` to ``out`` as plain tensors; returns the file's bytes."""
    import torch  # only when weights are written: planning never imports torch

    ds = store.open(item.partition.stage, item.key, item.stage.schema)
    read = registry.weights_reader(item.stage.schema.name) or unpack
    buffer = io.BytesIO()
    torch.save(read(ds.load()), buffer)
    data = buffer.getvalue()
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
        tmp = out.with_name(out.name + ".partial")
        tmp.write_bytes(data)
        tmp.replace(out)
    except OSError as exc:
        raise StorageError(f"cannot write weights to {out}: {exc.strerror}; choose another --out") from exc
    return data

"""`mocapflow train`: run a training catalog through the engine and export its weights artifact.

The catalog's per-dataset training stage (``train_fcn``, or a stage named with ``--stage`` that writes network
weights, like the suit's ``train_cornerdet``) produces the weights as a cached artifact (its key covers the
training data, every parameter and the code version); this module writes that artifact as a plain-tensor file for
the stage that uses the network, which loads it with ``torch.load(..., weights_only=True)``.
"""

from __future__ import annotations

import io
from pathlib import Path

from mocapflow.pipeline.errors import PlanError, StorageError
from mocapflow.pipeline.plan import Plan, WorkItem
from mocapflow.pipeline.storage import Store


def training_item(plan: Plan, catalog, stage: str | None) -> WorkItem:
    """The work item that trains the network: the named stage, else the catalog's one `train_fcn` stage."""
    names = [stage] if stage else [s.name for s in catalog.stages.values() if s.task == "train_fcn"]
    if len(names) != 1 or names[0] not in catalog.stages:
        raise PlanError(f"the catalog has {len(names)} train_fcn stages ({names}); name one with --stage")
    items = [i for i in plan.items.values() if i.partition.stage == names[0]]
    if len(items) != 1:
        raise PlanError(f"stage {names[0]!r} has {len(items)} partitions; a training stage is per dataset (one)")
    return items[0]


def export_weights(store: Store, item: WorkItem, out: Path) -> bytes:
    """Write the trained artifact of ``item`` to ``out`` as plain tensors; returns the file's bytes."""
    import torch

    from mocapflow.tasks.deepmocap.training import weights_from_dataset
    from mocapflow.tasks.shared.weights import unpack

    ds = store.open(item.partition.stage, item.key, item.stage.schema)
    buffer = io.BytesIO()
    if item.stage.schema.name == "fcn_weights":
        torch.save(weights_from_dataset(ds.load()), buffer)
    else:
        torch.save(unpack(ds.load()), buffer)
    data = buffer.getvalue()
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
        tmp = out.with_name(out.name + ".partial")
        tmp.write_bytes(data)
        tmp.replace(out)
    except OSError as exc:
        raise StorageError(f"cannot write weights to {out}: {exc.strerror}; choose another --out") from exc
    return data

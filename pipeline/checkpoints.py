"""A long task's checkpoint: the state a training saves as it goes, so a killed run continues where it stopped.

The engine hands a per-dataset task that declares ``checkpoints`` (registry.TaskSpec) a :class:`Checkpoint` for its
partition. The state lives beside the partition's uncommitted version (``<root>/<stage>/<key>/_checkpoint``), so it
belongs to one cache key: a changed parameter, input or code version starts afresh, the same run picks it up. It is
written with ``torch.save`` whole and then moved in place (a kill never leaves half of one) and read back with
``torch.load(..., weights_only=True)`` (tensors, numbers, strings, lists and dicts only: nothing is unpickled). The
commit of the partition drops it.
"""

from __future__ import annotations

import io
import logging
import pickle

from mocapflow.pipeline.errors import StorageError
from mocapflow.pipeline.storage import Store

log = logging.getLogger(__name__)

MAX_BYTES = 2 * 1024**3  # a checkpoint larger than this is refused at load (a network's state is megabytes)


class Checkpoint:
    """The checkpoint of one partition (``stage``, ``key``) of ``store``: ``load()`` and ``save(state)``."""

    def __init__(self, store: Store, stage: str, key: str):
        self.store, self.stage, self.key = store, stage, key

    @property
    def where(self) -> str:
        return f"{self.store.version_dir(self.stage, self.key)}/_checkpoint"

    def load(self) -> dict | None:
        """The state last saved for this partition, None if there is none."""
        import torch

        data = self.store.checkpoint(self.stage, self.key)
        if data is None:
            return None
        if len(data) > MAX_BYTES:
            raise StorageError(f"checkpoint {self.where} is {len(data) / 1e9:.1f} GB, over the {MAX_BYTES / 1e9:.1f} GB "
                               "a checkpoint may be; delete it to start the training afresh")
        try:
            state = torch.load(io.BytesIO(data), weights_only=True)
        except (pickle.UnpicklingError, RuntimeError, EOFError, ValueError, OSError) as exc:  # damaged or foreign
            first = (str(exc).strip().splitlines() or [""])[0][:200]
            raise StorageError(f"checkpoint {self.where} cannot be read ({type(exc).__name__}: {first}); delete it "
                               "to start the training afresh") from exc
        if not isinstance(state, dict):
            raise StorageError(f"checkpoint {self.where} holds a {type(state).__name__}, not a state dict; delete it "
                               "to start the training afresh")
        log.info("%s: resuming from its checkpoint", self.stage)
        return state

    def save(self, state: dict) -> None:
        import torch

        buffer = io.BytesIO()
        torch.save(state, buffer)
        self.store.save_checkpoint(self.stage, self.key, buffer.getvalue())

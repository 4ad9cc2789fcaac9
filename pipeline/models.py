"""Model weights on the workers: loaded once per process, never shipped through the task graph.

A task declares which of its parameters name weight files (``TaskSpec.weights_params``). The plan
hashes those files into the cache key; on a worker the runner replaces each such parameter with the
file's tensors, loaded with ``torch.load(..., weights_only=True)`` (plain tensors, no pickled code)
and kept in a small per-process cache keyed by the file's hash.
"""

from __future__ import annotations

import pickle
import threading

from mocapflow.pipeline.errors import StorageError
from mocapflow.pipeline.hashing import file_digest
from mocapflow.tasks.shared.cache import BoundedCache

_MAX_MODELS = 4
_CACHE: BoundedCache[str, dict] = BoundedCache(_MAX_MODELS)  # sha256 -> state dict
_LOADS_LOCK = threading.Lock()
loads = 0  # files actually read by this process (for tests and logs)


def load_weights(path: str, digest: str) -> dict:
    """The tensors in ``path``, whose sha256 must be ``digest`` (as planned); cached per process."""
    return _CACHE.get_or_make(digest, lambda: _load(path, digest))


def _load(path: str, digest: str) -> dict:
    global loads
    import torch

    actual = file_digest(path)
    if actual != digest:
        raise StorageError(f"weights {path} changed since the run was planned (sha256 {actual[:12]}, planned "
                           f"{digest[:12]}); rerun to plan with the new file")
    try:
        state = torch.load(path, map_location="cpu", weights_only=True)
    except (OSError, EOFError, RuntimeError, ValueError, pickle.UnpicklingError) as exc:
        raise StorageError(f"cannot load weights {path}: {exc}; it must hold plain tensors (a state dict)") from exc
    with _LOADS_LOCK:
        loads += 1
    return state

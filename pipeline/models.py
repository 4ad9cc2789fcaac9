"""Model weights on the workers: loaded once per process, never shipped through the task graph.

A task declares which of its parameters name weight files (``TaskSpec.weights_params``). The plan
hashes those files into the cache key; on a worker the runner replaces each such parameter with the
file's tensors, loaded with ``torch.load(..., weights_only=True)`` (plain tensors, no pickled code)
and kept in a small per-process cache keyed by the file's hash. A network in another runtime's format
(``RAW_FORMATS``: TensorFlow Lite, ONNX) is handed over as the file's bytes, for the task to give its runtime.
"""

from __future__ import annotations

import os
import pickle
import threading
from pathlib import Path

from mocapflow.pipeline.errors import StorageError
from mocapflow.pipeline.hashing import file_digest
from mocapflow.tasks.shared.cache import BoundedCache

_MAX_MODELS = 4
RAW_FORMATS = (".tflite", ".onnx")  # handed over as bytes
MAX_RAW_BYTES = 512 * 2**20  # a larger file is refused before it is read
_CACHE: BoundedCache[str, dict] = BoundedCache(_MAX_MODELS)  # sha256 -> state dict
_LOADS_LOCK = threading.Lock()
loads = 0  # files actually read by this process (for tests and logs)


def load_weights(path: str, digest: str) -> dict | bytes:
    """The tensors in ``path`` (the file's bytes for RAW_FORMATS), whose sha256 must be ``digest`` (as planned);
    cached per process."""
    return _CACHE.get_or_make(digest, lambda: _load(path, digest))


def _load(path: str, digest: str) -> dict | bytes:
    global loads
    import torch

    actual = file_digest(path)
    if actual != digest:
        raise StorageError(f"weights {path} changed since the run was planned (sha256 {actual[:12]}, planned "
                           f"{digest[:12]}); rerun to plan with the new file")
    if Path(path).suffix.lower() in RAW_FORMATS:
        return _raw(path)
    try:
        state = torch.load(path, map_location="cpu", weights_only=True)
    except (OSError, EOFError, RuntimeError, ValueError, pickle.UnpicklingError) as exc:
        raise StorageError(f"cannot load weights {path}: {exc}; it must hold plain tensors (a state dict)") from exc
    with _LOADS_LOCK:
        loads += 1
    return state


def _raw(path: str) -> bytes:
    global loads
    size = os.path.getsize(path)
    if size > MAX_RAW_BYTES:
        raise StorageError(f"model file {path} is {size:,} bytes, over the {MAX_RAW_BYTES:,}-byte limit for a "
                           "network handed to a task; check that it is the network meant")
    with open(path, "rb") as fh:
        data = fh.read()
    with _LOADS_LOCK:
        loads += 1
    return data

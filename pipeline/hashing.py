"""Canonical hashing for cache keys and input fingerprints."""

from __future__ import annotations

import dataclasses
import hashlib
import json
from typing import Any

KEY_LENGTH = 20


def canonical(obj: Any) -> Any:
    """A JSON-ready form of ``obj`` with a single spelling for equal values."""
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        return canonical(dataclasses.asdict(obj))
    if isinstance(obj, dict):
        return {str(k): canonical(v) for k, v in sorted(obj.items(), key=lambda kv: str(kv[0]))}
    if isinstance(obj, (list, tuple)):
        return [canonical(v) for v in obj]
    if isinstance(obj, float):
        return float(obj) if obj == obj else "nan"  # float(): a plain float also of a subclass such as np.float64
    if hasattr(obj, "item") and callable(obj.item):  # numpy scalar
        return canonical(obj.item())
    return obj


def canonical_json(obj: Any) -> str:
    return json.dumps(canonical(obj), sort_keys=True, separators=(",", ":"))


def digest(obj: Any, length: int = KEY_LENGTH) -> str:
    """Hex sha256 of the canonical JSON of ``obj`` (truncated to ``length``)."""
    return hashlib.sha256(canonical_json(obj).encode()).hexdigest()[:length]


def file_digest(path: str, fs=None, chunk: int = 1 << 20) -> str:
    """Full sha256 of a file's bytes (local path, or a path on the fsspec filesystem ``fs``)."""
    h = hashlib.sha256()
    opener = fs.open if fs is not None else open
    with opener(path, "rb") as fh:
        while block := fh.read(chunk):
            h.update(block)
    return h.hexdigest()

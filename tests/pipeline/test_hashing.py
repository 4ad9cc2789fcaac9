"""Cache-key hashing: one canonical JSON spelling per value, sha256 digests of it, and sha256 of files' bytes."""

from __future__ import annotations

import hashlib

import numpy as np

from mocapflow.pipeline.hashing import canonical, digest


def sha256(text: str) -> str:
    return hashlib.sha256(text.encode()).hexdigest()


def test_a_numpy_float64_hashes_as_the_python_float_it_holds():
    assert type(canonical(np.float64(0.25))) is float
    assert digest({"g": np.float64(0.25)}) == digest({"g": 0.25}) == sha256('{"g":0.25}')[:20]

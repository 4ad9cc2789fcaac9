"""Cache-key hashing: one canonical JSON spelling per value, sha256 digests of it, and sha256 of files' bytes."""

from __future__ import annotations

import hashlib
import math
from dataclasses import dataclass

import fsspec
import numpy as np
import pytest

from mocapflow.pipeline.hashing import KEY_LENGTH, canonical, canonical_json, digest, file_digest


def sha256(text: str) -> str:
    return hashlib.sha256(text.encode()).hexdigest()


@dataclass(frozen=True)
class Inner:
    gain: float
    taps: tuple[int, ...]


@dataclass(frozen=True)
class Params:
    name: str
    inner: Inner
    enabled: bool = True


NESTED = {"b": 1, "a": {"d": [1, (2, 3)], "c": 2.5}, "n": None, "t": True, "s": "x"}


def test_canonical_json_sorts_keys_drops_spaces_and_spells_tuples_as_lists():
    assert canonical_json(NESTED) == '{"a":{"c":2.5,"d":[1,[2,3]]},"b":1,"n":null,"s":"x","t":true}'


def test_digest_is_the_truncated_sha256_of_the_canonical_json():
    text = '{"a":{"c":2.5,"d":[1,[2,3]]},"b":1,"n":null,"s":"x","t":true}'
    assert KEY_LENGTH == 20
    assert digest(NESTED) == sha256(text)[:20] == "fa7f1ef133503e351904"  # cache keys on disk depend on this value
    assert digest(NESTED, length=8) == sha256(text)[:8]
    assert digest(NESTED, length=64) == sha256(text)


def test_digest_is_the_same_whatever_the_order_of_dict_keys():
    reordered = {"t": True, "s": "x", "n": None, "a": {"c": 2.5, "d": [1, (2, 3)]}, "b": 1}
    assert list(reordered) != list(NESTED)
    assert digest(reordered) == digest(NESTED)
    assert digest({"x": {"q": 1, "p": 2}}) == digest({"x": {"p": 2, "q": 1}}) == sha256('{"x":{"p":2,"q":1}}')[:20]


@pytest.mark.parametrize("changed", [
    {**NESTED, "b": 2},  # a value
    {**NESTED, "a": {"d": [1, (2, 4)], "c": 2.5}},  # a nested value
    {**NESTED, "a": {"d": [(2, 3), 1], "c": 2.5}},  # the order of a list
    {**NESTED, "t": False},
    {**NESTED, "n": 0},
    {**NESTED, "s": "y"},
    {k if k != "b" else "bb": v for k, v in NESTED.items()},  # a key
    {k: v for k, v in NESTED.items() if k != "n"},  # a key less
    {**NESTED, "extra": None},  # a key more
])
def test_digest_changes_with_any_value_key_or_list_order(changed):
    assert digest(changed) != digest(NESTED)


def test_a_dataclass_hashes_as_the_dict_of_its_fields():
    params = Params("flow", Inner(0.5, (3, 5)))
    assert canonical(params) == {"enabled": True, "inner": {"gain": 0.5, "taps": [3, 5]}, "name": "flow"}
    assert digest(params) == digest({"name": "flow", "inner": {"gain": 0.5, "taps": [3, 5]}, "enabled": True})
    assert digest(params) == sha256('{"enabled":true,"inner":{"gain":0.5,"taps":[3,5]},"name":"flow"}')[:20]
    assert digest(params) != digest(Params("flow", Inner(0.5, (3, 6))))


def test_numpy_scalars_hash_as_the_python_values_they_hold():
    assert canonical(np.int64(3)) == 3 and type(canonical(np.int64(3))) is int
    assert canonical(np.bool_(True)) is True
    assert digest({"k": np.int32(7), "g": np.float64(0.25)}) == digest({"k": 7, "g": 0.25})
    assert canonical_json(np.float32(0.1)) == "0.10000000149011612"  # float32's own value, not 0.1
    assert digest([np.int64(1), np.float64(2.5)]) == sha256("[1,2.5]")[:20]


def test_a_numpy_float64_hashes_as_the_python_float_it_holds():
    assert type(canonical(np.float64(0.25))) is float
    assert digest({"g": np.float64(0.25)}) == digest({"g": 0.25}) == sha256('{"g":0.25}')[:20]


def test_nan_has_one_spelling_so_equal_params_hash_equal():
    assert canonical(float("nan")) == "nan"
    assert digest({"t": float("nan")}) == digest({"t": np.float64("nan")}) == digest({"t": np.float32("nan")})
    assert digest({"t": float("nan")}) == sha256('{"t":"nan"}')[:20]


def test_floats_keep_their_exact_value():
    assert canonical_json([0.1, 1e-300, 2.0**60, -0.0]) == "[0.1,1e-300,1.152921504606847e+18,-0.0]"
    assert digest(0.1) != digest(math.nextafter(0.1, 1.0))  # the next float up is another key


def test_dict_keys_are_spelt_as_strings():
    assert canonical({1: "a", 2.5: "b"}) == {"1": "a", "2.5": "b"}
    assert canonical_json({10: 0, 9: 0}) == '{"10":0,"9":0}'  # sorted as strings


def test_file_digest_is_sha256_of_the_bytes_read_in_any_chunk_size(tmp_path):
    data = bytes(range(256)) * 41 + b"tail"
    path = tmp_path / "weights.pt"
    path.write_bytes(data)
    expected = hashlib.sha256(data).hexdigest()
    assert file_digest(str(path)) == expected
    assert file_digest(str(path), chunk=7) == expected  # many reads, a short last one
    assert len(expected) == 64
    empty = tmp_path / "empty"
    empty.write_bytes(b"")
    assert file_digest(str(empty)) == "e3b0c44298fc1c149afbf4c8996fb92427ae41e4649b934ca495991b7852b855"
    path.write_bytes(data[:-1] + b"!")
    assert file_digest(str(path)) != expected


def test_file_digest_reads_through_an_fsspec_filesystem():
    fs = fsspec.filesystem("memory")
    data = b"\x00\x01mocapflow" * 1000
    fs.pipe_file("/hashing-test/blob.bin", data)
    try:
        assert file_digest("/hashing-test/blob.bin", fs=fs, chunk=1000) == hashlib.sha256(data).hexdigest()
    finally:
        fs.rm("/hashing-test", recursive=True)

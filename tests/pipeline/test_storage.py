"""Storage: region writes store exactly what xarray's region writes store, and opened versions are reused only while
they are the same version."""

from __future__ import annotations

import filecmp

import numpy as np
import pytest
import xarray as xr

from mocapflow.pipeline.errors import StorageError
from mocapflow.pipeline.storage import Store, init_zarr
from mocapflow.schemas import ArtifactSchema, VarSpec

SCHEMA = ArtifactSchema("storage_test", 1, {
    "pos": VarSpec(("view", "frame", "reflector"), "float32"),
    "seen": VarSpec(("view", "frame", "y", "x"), "bool"),
    "label": VarSpec(("view", "frame", "y", "x"), "uint16"),
    "half": VarSpec(("view", "frame", "y", "x", "xyz"), "float16"),
    "area": VarSpec(("view", "blob"), "int32"),
}, frame_chunk=4)
N = 12


def dataset(frames: range, seed: int = 0) -> xr.Dataset:
    rng = np.random.default_rng(seed + frames.start)
    n = len(frames)
    pos = rng.normal(size=(1, n, 5)).astype(np.float32)
    pos[0, 0, 2] = np.nan
    return xr.Dataset(
        {"pos": (("view", "frame", "reflector"), pos),
         "seen": (("view", "frame", "y", "x"), rng.random((1, n, 6, 7)) < 0.3),
         "label": (("view", "frame", "y", "x"), rng.integers(0, 9, (1, n, 6, 7)).astype(np.uint16)),
         "half": (("view", "frame", "y", "x", "xyz"), rng.normal(size=(1, n, 6, 7, 3)).astype(np.float16)),
         "area": (("view", "blob"), np.array([[4, 2]], np.int32))},
        coords={"view": ["cam0"], "frame": np.arange(frames.start, frames.stop)})


def write(store: Store, key: str, seed: int = 0) -> None:
    for start in range(0, N, 4):
        store.write_region("s", key, SCHEMA, dataset(range(start, start + 4), seed), N, start, start + 4)
    store.commit("s", key, {"partition": "s"})


def test_regions_store_the_bytes_xarrays_region_writes_store(tmp_path):
    store = Store(str(tmp_path / "a"))
    write(store, "k")
    reference = str(tmp_path / "b.zarr")  # the same regions through xarray's own region write
    init_zarr(reference, SCHEMA, dataset(range(0, 4)), N)
    for start in range(0, N, 4):
        ds = dataset(range(start, start + 4))
        ds.drop_vars(["area", "view"]).to_zarr(reference, region={"frame": slice(start, start + 4)}, consolidated=False,
                                               write_empty_chunks=True)
    ours = tmp_path / "a" / "s" / "k" / "data.zarr"
    chunks = sorted(p.relative_to(ours) for p in ours.rglob("*") if p.is_file() and "/c/" in p.as_posix())
    assert len(chunks) >= 4 * 3  # every frame-chunked variable wrote its 3 chunks
    for name in chunks:
        assert filecmp.cmp(ours / name, f"{reference}/{name}", shallow=False), name
    back = store.open("s", "k", SCHEMA).load()
    whole = xr.concat([dataset(range(s, s + 4)) for s in range(0, N, 4)], dim="frame", data_vars="minimal")
    for name in ("pos", "seen", "label", "half"):
        np.testing.assert_array_equal(back[name].values, whole[name].values)


def test_an_opened_version_is_reused_until_it_is_written_again(tmp_path):
    store = Store(str(tmp_path))
    with pytest.raises(StorageError, match="not complete"):
        store.open("s", "k", SCHEMA)
    write(store, "k", seed=0)
    first = store.open("s", "k", SCHEMA)
    loaded = first.load()
    again = store.open("s", "k", SCHEMA)
    assert not isinstance(again["label"].variable._data, np.ndarray)  # loading a copy left the kept one lazy
    np.testing.assert_array_equal(again["label"].values, loaded["label"].values)

    store.remove_version("s", "k")
    with pytest.raises(StorageError, match="not complete"):
        store.open("s", "k", SCHEMA)
    write(store, "k", seed=100)  # the same key written again with other values
    fresh = Store(str(tmp_path)).open("s", "k", SCHEMA).load()
    assert not np.array_equal(fresh["label"].values, loaded["label"].values)
    np.testing.assert_array_equal(fresh["label"].values[:, :4], dataset(range(0, 4), seed=100)["label"].values)

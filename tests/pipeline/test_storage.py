"""Storage: region writes store exactly what xarray's region writes store, and opened versions are reused only while
they are the same version."""

from __future__ import annotations

import filecmp

import numpy as np
import pytest
import xarray as xr

from mocapflow.pipeline.errors import SchemaError, StorageError
from mocapflow.pipeline.storage import Store, init_zarr, write_zarr_region
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


def test_a_region_equal_to_the_fill_value_still_writes_its_chunks(tmp_path):
    store = Store(str(tmp_path))
    for start in range(0, N, 4):
        ds = dataset(range(start, start + 4))
        if start == 4:
            for name in ("pos", "seen", "label", "half"):
                ds[name] = xr.zeros_like(ds[name])
        store.write_region("s", "k", SCHEMA, ds, N, start, start + 4)
    store.commit("s", "k", {"partition": "s"})
    data = tmp_path / "s" / "k" / "data.zarr"
    for name in ("pos", "seen", "label", "half"):
        frame_chunks = sorted(p.relative_to(data / name / "c").parts[1] for p in (data / name / "c").rglob("*") if p.is_file())
        assert frame_chunks == ["0", "1", "2"], name  # the zero region's chunk is on disk, as xarray writes it
    back = store.open("s", "k", SCHEMA).load()
    assert not back["label"].values[:, 4:8].any()
    np.testing.assert_array_equal(back["label"].values[:, 8:], dataset(range(8, 12))["label"].values)


def test_the_installed_zarr_is_one_region_writes_are_tested_on():
    """write_zarr_region runs on zarr internals: a zarr outside the pinned range (or without them) fails here."""
    import tomllib
    from pathlib import Path

    import zarr
    from packaging.requirements import Requirement
    from packaging.specifiers import SpecifierSet

    from mocapflow.pipeline.storage import ZARR_RANGE

    pyproject = tomllib.loads((Path(__file__).resolve().parents[2] / "pyproject.toml").read_text())
    pinned = next(r.specifier for r in map(Requirement, pyproject["project"]["dependencies"]) if r.name == "zarr")
    assert pinned == SpecifierSet(ZARR_RANGE), f"pyproject.toml pins zarr{pinned}, storage.ZARR_RANGE says {ZARR_RANGE}"
    assert zarr.__version__ in pinned, (f"zarr {zarr.__version__} is outside the tested range {ZARR_RANGE}: run this "
                                        "module and benchmarks/region_write.py on it before widening the pin")

    from zarr.core.sync import sync

    async def answer():
        return 42

    assert sync(answer()) == 42
    assert callable(zarr.AsyncArray.with_config)


def test_a_region_whose_frames_are_not_the_regions_is_refused_naming_stage_frames_and_fix(tmp_path):
    store = Store(str(tmp_path))
    shifted = dataset(range(0, 4)).assign_coords(frame=np.arange(1, 5))
    with pytest.raises(SchemaError, match=r"stage 's' for frames 0-4 .* frame coordinate \[1, 2, 3, 4\], "
                                          r"expected 0\.\.3; the task must return exactly the frames"):
        store.write_region("s", "k", SCHEMA, shifted, N, 0, 4)
    long = dataset(range(0, 12)).assign_coords(frame=np.arange(12)[::-1])
    with pytest.raises(SchemaError, match=r"\[11, 10, \.\.\., 0\] \(12 frames\), expected 0\.\.11"):
        store.write_region("s", "k", SCHEMA, long, N, 0, 12)
    assert not (tmp_path / "s" / "k" / "data.zarr").exists()  # refused before anything was written
    store.write_region("s", "k", SCHEMA, dataset(range(0, 4)), N, 0, 4)  # the right frames are written
    assert store.region_done("s", "k", 0, 4)


def test_a_region_whose_dims_differ_from_the_stored_arrays_is_refused_before_any_write(tmp_path):
    target = str(tmp_path / "t.zarr")
    init_zarr(target, SCHEMA, dataset(range(0, 4)), N)
    before = sorted(p.relative_to(tmp_path) for p in tmp_path.rglob("*") if p.is_file())
    region = dataset(range(4, 8))
    region["label"] = region["label"].transpose("frame", "view", "y", "x")
    with pytest.raises(StorageError, match=r"t\.zarr: array 'label' is stored with dims \('view', 'frame', 'y', 'x'\), "
                                           r"but the region of frames 4-8 to write has dims \('frame', 'view', 'y', 'x'\);"
                                           r".* delete .*t\.zarr"):
        write_zarr_region(target, region, 4, 8)
    after = sorted(p.relative_to(tmp_path) for p in tmp_path.rglob("*") if p.is_file())
    assert after == before  # no array of the region was written
    write_zarr_region(target, dataset(range(4, 8)), 4, 8)
    assert len([p for p in tmp_path.rglob("*") if p.is_file()]) > len(before)


def test_threads_opening_one_complete_version_open_it_once(tmp_path, monkeypatch):
    import threading
    import time

    store = Store(str(tmp_path))
    write(store, "k")
    opened, real = [], xr.open_zarr

    def slow_open(*args, **kwargs):
        opened.append(args[0])
        time.sleep(0.05)  # every other thread asks for the version meanwhile
        return real(*args, **kwargs)

    monkeypatch.setattr(xr, "open_zarr", slow_open)
    labels = []
    threads = [threading.Thread(target=lambda: labels.append(store.open("s", "k", SCHEMA)["label"].values))
               for _ in range(8)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(timeout=30)
    assert len(opened) == 1 and str(opened[0]).endswith(str(tmp_path / "s" / "k" / "data.zarr"))  # a checking store
    assert len(labels) == 8
    for label in labels:
        np.testing.assert_array_equal(label[:, :4], dataset(range(0, 4))["label"].values)

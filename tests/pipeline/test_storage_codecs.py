"""Storage codecs: every variable of the per-view stages reads back exactly as written, and the codecs chosen by
dtype and layout take less disk than zstd alone where they are used."""

from __future__ import annotations

import json

import numpy as np
import xarray as xr
import zarr
from zarr.codecs import ZstdCodec

from mocapflow.pipeline.storage import Store
from mocapflow.schemas import ArtifactSchema, VarSpec
from mocapflow.schemas.stages import REFLECTOR_MASKS, SCENE_FLOW

H, W, N = 48, 64, 16
DIMS = ("view", "frame", "y", "x")


def scene_flow(frames: range) -> xr.Dataset:
    """Flow as the stage writes it: motion and colours inside a valid box, 0 and 128 (no motion) elsewhere."""
    rng = np.random.default_rng(frames.start)
    n = len(frames)
    valid = np.zeros((1, n, H, W), bool)
    valid[:, :, 10:30, 20:50] = True
    motion = np.where(valid[..., None], rng.normal(0.0, 0.01, (1, n, H, W, 3)), 0.0).astype(np.float16)
    colored = np.where(valid[..., None], rng.integers(0, 256, (1, n, H, W, 3)), 128).astype(np.uint8)
    return xr.Dataset({"flow": (DIMS + ("xyz",), motion), "valid": (DIMS, valid),
                       "colorized_flow": (DIMS + ("rgb",), colored)},
                      coords={"view": ["cam0"], "frame": np.arange(frames.start, frames.stop),
                              "xyz": np.array(["x", "y", "z"], object), "rgb": np.array(["r", "g", "b"], object)},
                      attrs={"color_scale_m": 0.05})


def reflector_masks(frames: range) -> xr.Dataset:
    rng = np.random.default_rng(100 + frames.start)
    n = len(frames)
    blob_id = rng.integers(0, 40, (1, n, H, W)).astype(np.uint16)
    return xr.Dataset({"mask": (DIMS, blob_id > 0), "blob_id": (DIMS, blob_id),
                       "blob_area": (("view", "frame", "blob"), rng.integers(0, 500, (1, n, 64)).astype(np.int32)),
                       "colorized_depth": (DIMS + ("rgb",), rng.integers(0, 256, (1, n, H, W, 3)).astype(np.uint8))},
                      coords={"view": ["cam0"], "frame": np.arange(frames.start, frames.stop),
                              "rgb": np.array(["r", "g", "b"], object)},
                      attrs={"ir_threshold": 30000, "near_mm": 1000.0, "far_mm": 4000.0})


def write_and_read(tmp_path, schema, make) -> tuple[xr.Dataset, xr.Dataset]:
    store = Store(str(tmp_path))
    for start in range(0, N, 8):
        store.write_region("s", "k", schema, make(range(start, start + 8)), N, start, start + 8)
    store.commit("s", "k", {"partition": "s"})
    whole = xr.concat([make(range(s, s + 8)) for s in range(0, N, 8)], dim="frame", data_vars="minimal")
    return store.open("s", "k", schema).load(), whole


def codec_names(tmp_path, name: str) -> list[str]:
    meta = json.loads((tmp_path / "s" / "k" / "data.zarr" / name / "zarr.json").read_text())
    return [c["name"] for c in meta["codecs"]]


def test_scene_flow_reads_back_exactly_zero_where_invalid_and_the_motion_elsewhere(tmp_path):
    back, written = write_and_read(tmp_path, SCENE_FLOW, scene_flow)
    for name in ("flow", "valid", "colorized_flow"):
        np.testing.assert_array_equal(back[name].values, written[name].values)
    valid = back["valid"].values
    assert valid.sum() == N * 20 * 30
    assert not back["flow"].values[~valid].any() and (back["colorized_flow"].values[~valid] == 128).all()
    np.testing.assert_array_equal(back["flow"].values[valid], written["flow"].values[valid])  # the motion, untouched
    assert codec_names(tmp_path, "flow") == ["transpose", "bytes", "zstd"]  # channels stored as planes
    assert codec_names(tmp_path, "valid") == ["bytes", "zstd"]


def test_reflector_masks_read_back_exactly(tmp_path):
    back, written = write_and_read(tmp_path, REFLECTOR_MASKS, reflector_masks)
    for name in ("mask", "blob_id", "blob_area", "colorized_depth"):
        np.testing.assert_array_equal(back[name].values, written[name].values)
    assert codec_names(tmp_path, "blob_id") == ["bytes", "blosc"]
    assert codec_names(tmp_path, "colorized_depth") == ["bytes", "zstd"]


COUNTS = ArtifactSchema("codec_test", 1, {"ir": VarSpec(DIMS, "uint16", "counts")}, frame_chunk=8)


def counts(frames: range) -> xr.Dataset:
    """A sensor-like 16-bit image: a smooth gradient of a few thousand counts plus noise of a few counts."""
    rng = np.random.default_rng(7 + frames.start)
    gradient = 2000.0 + 30.0 * np.arange(W)[None, :] + 20.0 * np.arange(H)[:, None]
    ir = gradient + rng.normal(0.0, 4.0, (1, len(frames), H, W))
    return xr.Dataset({"ir": (DIMS, np.rint(ir).astype(np.uint16))},
                      coords={"view": ["cam0"], "frame": np.arange(frames.start, frames.stop)})


def test_16_bit_counts_read_back_exactly_in_less_disk_than_zstd_alone(tmp_path):
    back, written = write_and_read(tmp_path, COUNTS, counts)
    np.testing.assert_array_equal(back["ir"].values, written["ir"].values)
    ours = sum(p.stat().st_size for p in (tmp_path / "s" / "k" / "data.zarr" / "ir" / "c").rglob("*") if p.is_file())
    plain = zarr.create_array(zarr.storage.LocalStore(tmp_path / "plain.zarr"), shape=(1, N, H, W), chunks=(1, 8, H, W),
                              dtype="uint16", compressors=ZstdCodec(level=1), fill_value=0)
    plain[:] = written["ir"].values
    zstd_alone = sum(p.stat().st_size for p in (tmp_path / "plain.zarr" / "c").rglob("*") if p.is_file())
    assert ours < 0.8 * zstd_alone, (ours, zstd_alone)

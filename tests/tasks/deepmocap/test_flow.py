"""3D optical flow, both variants: a textured plane under known rigid motion, zero motion, holes, schema."""

from __future__ import annotations


import numpy as np
import pytest
import xarray as xr

from conftest import plane_sequence
from mocapflow.schemas import get_schema
from mocapflow.tasks.deepmocap.flow import DisConfig, PrimalDualConfig, dis, gather_rows, ir_to_8bit, scatter_rows, subject_box
from mocapflow.tasks.deepmocap.pdflow import primal_dual

VARIANTS = {"dis": lambda ds: dis(ds, DisConfig()),
            "primal_dual": lambda ds: primal_dual(ds, PrimalDualConfig(device="cpu"))}


def interior(valid):
    region = np.zeros_like(valid)
    region[..., 20:-20, 25:-25] = True
    return region & valid


@pytest.mark.parametrize("variant", sorted(VARIANTS))
def test_rigid_translation_of_a_plane_gives_the_known_3d_flow(variant):
    step = np.array([0.012, -0.008, 0.015])
    out = VARIANTS[variant](plane_sequence([step, step]))
    get_schema("scene_flow").validate(out)
    flow, valid = out.flow.values[0].astype(np.float32), out.valid.values[0]
    assert not valid[0].any() and not flow[0].any()  # the first frame has no predecessor
    for k in (1, 2):
        ok = interior(valid[k])
        assert ok.sum() > 0.9 * interior(np.ones_like(valid[k])).sum()
        err = np.linalg.norm(flow[k][ok] - step, axis=-1)
        assert np.median(err) < 0.0015, f"{variant} frame {k}: median error {np.median(err) * 1000:.2f} mm"


@pytest.mark.parametrize("variant", sorted(VARIANTS))
def test_zero_motion_gives_near_zero_flow(variant):
    out = VARIANTS[variant](plane_sequence([np.zeros(3)]))
    ok = interior(out.valid.values[0, 1])
    assert np.percentile(np.linalg.norm(out.flow.values[0, 1][ok].astype(np.float32), axis=-1), 95) < 0.0005


@pytest.mark.parametrize("variant", sorted(VARIANTS))
def test_reflector_holes_do_not_bleed_motion(variant):
    step = np.array([0.01, 0.0, 0.0])
    ds = plane_sequence([step], hole=(0.0, 0.0))
    out = VARIANTS[variant](ds)
    hole = ds.depth.values[0, 1] == 0
    assert hole.sum() > 50
    flow, valid = out.flow.values[0, 1].astype(np.float32), out.valid.values[0, 1]
    assert not valid[hole].any() and not flow[hole].any()
    ring = np.zeros_like(hole)
    ys, xs = np.nonzero(hole)
    ring[ys.min() - 8:ys.max() + 9, xs.min() - 8:xs.max() + 9] = True
    ring &= ~hole & valid
    assert ring.sum() > 100
    assert np.median(np.linalg.norm(flow[ring] - step, axis=-1)) < 0.002


def test_invalid_depth_is_never_reported_as_motion():
    ds = plane_sequence([np.array([0.01, 0.0, 0.0])])
    depth = ds.depth.values.copy()
    depth[0, 0, :, :40] = 0  # the previous frame lost its left part
    out = dis(ds.assign(depth=(("view", "frame", "y", "x"), depth)), DisConfig())
    valid = out.valid.values[0, 1]
    assert not valid[:, :35].any()  # correspondences would land on missing depth
    assert valid[:, 60:140].mean() > 0.9


def test_unknown_dis_preset_is_a_clear_error():
    with pytest.raises(ValueError, match="unknown DIS preset 'turbo'"):
        dis(plane_sequence([np.zeros(3)]), DisConfig(preset="turbo"))


def test_flow_dataset_dims_are_named():
    out = dis(plane_sequence([np.zeros(3)]), DisConfig())
    assert out.flow.dims == ("view", "frame", "y", "x", "xyz") and isinstance(out, xr.Dataset)


def test_subject_box_grows_the_bright_pixels_box_and_stays_inside_the_image():
    a, b = np.zeros((100, 120)), np.zeros((100, 120))
    a[40:45, 50:52], b[47, 60] = 40000, 40000  # the reflectors of both frames count
    assert subject_box(a, b, threshold=30000, margin_px=10, min_side_px=8) == (slice(30, 58), slice(40, 71))
    assert subject_box(a, b, threshold=30000, margin_px=0, min_side_px=30) == (slice(29, 59), slice(40, 71))
    a[2, 118] = 40000  # near the edges: clipped to the image
    assert subject_box(a, b, threshold=30000, margin_px=10, min_side_px=8) == (slice(0, 58), slice(40, 120))
    assert subject_box(np.zeros((100, 120)), b * 0, threshold=30000, margin_px=10) == (slice(0, 100), slice(0, 120))


def test_flow_around_the_subject_only_matches_the_whole_image_there_and_is_empty_elsewhere():
    step = np.array([0.01, 0.0, 0.0])
    ds = plane_sequence([step], hole=(0.0, 0.0))  # the hole is a reflector: saturated IR
    whole, around = dis(ds, DisConfig(roi_ir=0.0)), dis(ds, DisConfig(roi_ir=30000.0, roi_margin_px=24))
    get_schema("scene_flow").validate(around)
    rows, cols = subject_box(ds.ir.values[0, 1], ds.ir.values[0, 0], threshold=30000, margin_px=24)
    inside = np.zeros(ds.ir.shape[2:], bool)
    inside[rows, cols] = True
    assert 0.01 < inside.mean() < 0.5  # a real crop of the image
    flow, valid = around.flow.values[0, 1].astype(np.float32), around.valid.values[0, 1]
    assert not valid[~inside].any() and not flow[~inside].any()
    assert (around.colorized_flow.values[0, 1][~inside] == 128).all()
    ring = valid & whole.valid.values[0, 1]
    assert ring.sum() > 100
    assert np.median(np.linalg.norm(flow[ring] - step, axis=-1)) < 0.002
    np.testing.assert_allclose(np.median(flow[ring], axis=0), np.median(whole.flow.values[0, 1][ring], axis=0), atol=5e-4)
    with pytest.raises(ValueError, match="roi_ir"):
        DisConfig(roi_ir=-1.0)
    assert DisConfig().roi_ir == 30000.0  # around the subject unless a catalog asks for the whole image


def test_ir_to_8bit_table_is_the_formula_for_every_16bit_count():
    counts = np.arange(65536, dtype=np.uint16).reshape(256, 256)
    formula = np.rint(255.0 * np.sqrt(np.clip(counts.astype(np.float32) / 9000.0, 0.0, 1.0))).astype(np.uint8)
    assert np.array_equal(ir_to_8bit(counts, 9000.0), formula)
    assert np.array_equal(ir_to_8bit(counts.astype(np.float32), 9000.0), formula)  # other dtypes: the formula itself


def test_row_gather_and_scatter_match_fancy_indexing():
    rng = np.random.default_rng(3)
    image = rng.normal(size=(7, 9, 3)).astype(np.float32)
    at = np.array([0, 5, 17, 62])
    assert np.array_equal(gather_rows(image, at), image.reshape(-1, 3)[at])
    crop = image[2:6, 1:8]  # a view, not contiguous
    assert np.array_equal(gather_rows(crop, np.array([1, 27])), crop.reshape(-1, 3)[[1, 27]])
    out, expected = np.zeros((7, 9, 3), np.float16), np.zeros((7, 9, 3), np.float16)
    values = rng.normal(size=(4, 3)).astype(np.float32)
    scatter_rows(out, at, values)
    expected.reshape(-1, 3)[at] = values
    assert np.array_equal(out.view(np.uint16), expected.view(np.uint16))

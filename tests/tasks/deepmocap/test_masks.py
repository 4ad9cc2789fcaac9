"""Reflector masks and colorized depth on hand-made images."""

from __future__ import annotations


import cv2
import numpy as np
import xarray as xr

from mocapflow.schemas import get_schema
from mocapflow.tasks.deepmocap.masks import MaskConfig, colorize_depth, masks, reflector_mask

KW = dict(threshold=30000, open_px=0, close_px=1, min_area=2, max_components=8)


def test_blobs_are_found_with_their_areas_and_specks_dropped():
    ir = np.full((40, 60), 2000, np.uint16)
    ir[5:10, 5:10] = 65000  # 25 px
    ir[20:23, 30:33] = 64000  # 9 px
    ir[30, 50] = 65000  # a one-pixel speck: below min_area
    ir[12:14, 40:42] = 65000  # 4 px ...
    ir[14:16, 42:44] = 65000  # ... touching it diagonally: one 8-connected blob of 8 px
    mask, labels, areas = reflector_mask(ir, **{**KW, "close_px": 0})
    assert list(areas[:4]) == [25, 9, 8, 0]  # numbered by decreasing area
    assert labels[7, 7] == 1 and labels[21, 31] == 2 and labels[13, 41] == labels[15, 43] == 3
    assert not mask[30, 50] and mask.sum() == 42
    _, _, closed = reflector_mask(ir, **KW)
    assert list(closed[:3]) == [25, 10, 9]  # closing fills the two corners joining the diagonal pair


def test_closing_fills_a_pinhole_and_threshold_is_respected():
    ir = np.full((20, 20), 1000, np.uint16)
    ir[5:12, 5:12] = 65000
    ir[8, 8] = 1000  # a dark pinhole inside the blob
    ir[15:18, 15:18] = 29999  # just under the threshold
    mask, labels, areas = reflector_mask(ir, **KW)
    assert mask[8, 8] and areas[0] == 49 and areas[1] == 0
    _, _, no_close = reflector_mask(ir, **{**KW, "close_px": 0})
    assert no_close[0] == 48


def test_colorized_depth_is_jet_with_reflectors_and_holes_black():
    depth = np.array([[1000, 4000, 0, 2500]], np.uint16)
    mask = np.array([[False, False, False, True]])
    rgb = colorize_depth(depth, mask, near_mm=1000, far_mm=4000)
    near, far = rgb[0, 0].astype(int), rgb[0, 1].astype(int)
    assert near[0] > near[2] and far[2] > far[0]  # near is red, far is blue (RGB order)
    assert (rgb[0, 2] == 0).all() and (rgb[0, 3] == 0).all()


def test_colorized_depth_is_opencvs_jet_of_the_linear_level_at_every_depth():
    rng = np.random.default_rng(0)
    depth = rng.integers(0, 6000, (24, 31)).astype(np.uint16)  # before, inside and beyond [near, far], and 0
    depth[0, :4] = [0, 500, 500 + 1, 65535]
    mask = rng.random((24, 31)) < 0.1
    rgb = colorize_depth(depth, mask, near_mm=500, far_mm=3500)
    level = np.rint(255 * (1 - np.clip((depth.astype(np.float32) - 500) / 3000, 0, 1))).astype(np.uint8)
    expected = cv2.applyColorMap(level, cv2.COLORMAP_JET)[..., ::-1].copy()  # RGB
    expected[(depth == 0) | mask] = 0
    np.testing.assert_array_equal(rgb, expected)


def test_stage_output_matches_its_schema():
    ir = np.full((2, 3, 16, 20), 1000, np.uint16)
    ir[:, :, 4:8, 4:8] = 65000
    depth = np.full_like(ir, 2500)
    frames = xr.Dataset({"ir": (("view", "frame", "y", "x"), ir), "depth": (("view", "frame", "y", "x"), depth)},
                        coords={"view": np.array(["a", "b"], dtype=object), "frame": np.arange(3)})
    out = masks(frames, MaskConfig())
    get_schema("reflector_masks").validate(out)
    assert out.blob_area.values[1, 2, 0] == 16 and (out.colorized_depth.values[0, 0, 5, 5] == 0).all()


def _whole_image_mask(ir, *, threshold, open_px, close_px, min_area, max_components):
    """The whole-image form of reflector_mask (morphology and components over every pixel)."""
    mask = (ir >= threshold).astype(np.uint8)
    disk = lambda r: cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1, 2 * r + 1))  # noqa: E731
    if open_px:
        mask = cv2.morphologyEx(mask, cv2.MORPH_OPEN, disk(open_px))
    if close_px:
        mask = cv2.morphologyEx(mask, cv2.MORPH_CLOSE, disk(close_px))
    count, labels, stats, _ = cv2.connectedComponentsWithStats(mask, connectivity=8)
    area = stats[1:, cv2.CC_STAT_AREA]
    keep = np.flatnonzero(area >= min_area)
    keep = keep[np.argsort(-area[keep], kind="stable")][:max_components]
    relabel = np.zeros(count, np.uint16)
    relabel[keep + 1] = np.arange(1, len(keep) + 1)
    areas = np.zeros(max_components, np.int32)
    areas[:len(keep)] = area[keep]
    return relabel[labels] > 0, relabel[labels], areas


def test_the_box_around_bright_pixels_gives_the_whole_images_masks_labels_and_areas():
    rng = np.random.default_rng(4)
    for trial in range(60):
        ir = rng.integers(0, 29000, (48, 64)).astype(np.uint16)
        for _ in range(rng.integers(0, 7)):  # blobs anywhere, borders and corners included
            y, x = rng.integers(0, 48), rng.integers(0, 64)
            h, w = rng.integers(1, 5, 2)
            ir[y:y + h, x:x + w] = 65000
        ir[rng.random(ir.shape) < 0.01] = 65000  # specks
        kw = dict(threshold=30000, open_px=int(trial % 2), close_px=int(trial % 3), min_area=2, max_components=8)
        for got, want in zip(reflector_mask(ir, **kw), _whole_image_mask(ir, **kw)):
            np.testing.assert_array_equal(got, want)
    empty = reflector_mask(np.zeros((8, 8), np.uint16), **KW)
    assert not empty[0].any() and not empty[1].any() and not empty[2].any() and empty[1].dtype == np.uint16

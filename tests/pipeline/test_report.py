"""The report's 2D overlay: estimates filled, recovered estimates hollow, true positions as rings."""

import numpy as np

from mocapflow.pipeline.report import overlay


def test_overlay_draws_a_recovered_estimate_hollow():
    ir = np.full((60, 80), 500.0)
    ir[0, 0] = 1000.0  # the gain: the body at about half scale
    xy = np.array([[20.0, 30.0], [50.0, 30.0], [np.nan, np.nan]])
    gt = np.array([[np.nan, np.nan], [np.nan, np.nan], [65.0, 15.0]])
    img = overlay(ir, xy, gt, ["A", "B", "C"], "", np.array([False, True, False]))
    background = img[45, 5].copy()
    assert (img[30, 20] != background).any()  # a plain estimate: a filled dot
    np.testing.assert_array_equal(img[30, 50], background)  # a recovered one: its centre left as it was ...
    assert (img[30, 53] != background).any()  # ... inside a ring of its colour
    np.testing.assert_array_equal(img[15, 71], [255, 255, 255])  # the true position of C: a white ring
    np.testing.assert_array_equal(img[15, 65], background)
    plain = overlay(ir, xy, gt, ["A", "B", "C"], "")
    assert (plain[30, 50] != background).any()  # without the flag every estimate is filled

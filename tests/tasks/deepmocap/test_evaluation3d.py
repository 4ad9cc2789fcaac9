"""The 3D marker figures on a hand-made error set: median, mean, the tail (p95, p99 by linear interpolation
between order statistics, share > 10 cm of the marker-frames with a value), completeness, and per marker
the tail over time with the worst markers first."""

import numpy as np
import pytest

from mocapflow.tasks.deepmocap.evaluation import summarize_markers
from mocapflow.tasks.shared.marker_errors import marker_tails, tail, worst_markers


def test_tail_of_a_hand_made_error_set():
    errors = np.full((2, 11), np.nan)  # (frame, reflector) mm; one marker-frame missing
    errors.flat[:21] = np.arange(21) * 10.0  # 0, 10, ..., 200 mm
    out = summarize_markers(errors, [f"r{k}" for k in range(11)])
    # sorted values v_0..v_20 = 10 k: p95 at rank 0.95 * 20 = 19 -> 190; p99 at 19.8 -> 190 + 0.8 * 10 = 198
    assert out["p95_mm"] == pytest.approx(190.0) and out["p99_mm"] == pytest.approx(198.0)
    assert out["gross_share"] == pytest.approx(10 / 21)  # 110 ... 200 mm are more than 100 mm off
    assert out["median_mm"] == pytest.approx(100.0) and out["mean_mm"] == pytest.approx(100.0)
    assert out["completeness"] == pytest.approx(21 / 22)
    assert out["per_reflector_median_mm"]["r10"] == pytest.approx(100.0)  # 100 mm; its frame-1 value is missing


def test_exactly_ten_centimetres_is_not_gross_and_nothing_gives_nan():
    assert tail(np.array([100.0, 100.0, 100.1, 5.0]))["gross_share"] == pytest.approx(0.25)
    assert all(np.isnan(v) for v in tail(np.array([])).values())


def test_the_worst_markers_rank_by_p95_then_by_the_largest_error():
    errors = np.full((40, 4), 1.0)  # (frame, marker) mm
    errors[:, 0] = 30.0  # 3 cm off throughout: ahead of marker 1's larger single error (p95 ranks first)
    errors[:, 3] = np.nan  # never tracked: last, its figures NaN
    errors[5, 1] = 50.0  # one frame off: p95 1 mm (rank 0.95 * 39 = 37.05 of 39 x 1 mm)
    errors[[2, 3, 6], 2], errors[4, 2] = 150.0, np.nan  # 3 of its 39 frames > 10 cm
    tails = marker_tails(errors)
    # marker 2: 36 x 1 mm, 3 x 150 mm; p95 at rank 0.95 * 38 = 36.1 -> 150
    assert tails["p95_mm"][2] == pytest.approx(150.0) and tails["p95_mm"][1] == pytest.approx(1.0)
    np.testing.assert_array_equal(tails["max_mm"][:3], [30.0, 50.0, 150.0])
    np.testing.assert_array_equal(tails["max_frame"], [0, 5, 2, -1])
    np.testing.assert_array_equal(tails["gross_frames"], [0, 0, 3, 0])
    assert tails["gross_share"][2] == pytest.approx(3 / 39) and np.isnan(tails["gross_share"][3])
    assert np.isnan(tails["max_mm"][3]) and np.isnan(tails["p95_mm"][3])
    np.testing.assert_array_equal(worst_markers(errors, k=3), [2, 0, 1])
    np.testing.assert_array_equal(worst_markers(errors, k=9), [2, 0, 1, 3])
    errors[:, 0] = 1.0  # a tie at p95 1 mm: the larger maximum first
    np.testing.assert_array_equal(worst_markers(errors, k=3), [2, 1, 0])

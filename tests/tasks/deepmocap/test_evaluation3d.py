"""The 3D marker figures on a hand-made error set: median, mean, the tail (p95, p99 by linear interpolation
between order statistics, share > 10 cm of the marker-frames with a value) and completeness."""

import numpy as np
import pytest

from mocapflow.tasks.deepmocap.evaluation import summarize_markers, tail


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

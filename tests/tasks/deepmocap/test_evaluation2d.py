"""2D evaluation: AP on a hand-computed precision-recall curve, PCK radius, ignored barely-visible reflectors."""

import numpy as np
import pytest

from mocapflow.tasks.deepmocap.evaluation import Matches2D, average_precision, match_2d, pck_radius, summarize_2d


def test_average_precision_by_hand():
    # ranked: TP, FP, TP with 2 positives -> precision 1, 1/2, 2/3 at recall 1/2, 1/2, 1
    assert average_precision([0.9, 0.8, 0.7], [True, False, True], 2) == pytest.approx(0.5 * 1 + 0.5 * 2 / 3)
    assert average_precision([0.9, 0.8], [True, True], 4) == pytest.approx(0.5)  # half the positives found
    assert average_precision([], [], 3) == 0.0
    assert np.isnan(average_precision([0.5], [False], 0))


def test_pck_radius_is_alpha_of_the_longer_box_side():
    body = np.zeros((100, 100), bool)
    body[10:90, 30:50] = True  # 80 x 20
    assert pck_radius(body) == pytest.approx(4.0)


def test_matching_counts_positives_and_ignores_barely_visible():
    m = Matches2D(3)
    gt = np.array([[10.0, 10.0], [50.0, 50.0], [80.0, 20.0]])
    xy = np.array([[11.0, 10.0], [60.0, 50.0], [80.0, 21.0]])
    match_2d(m, xy, np.array([0.9, 0.8, 0.7]), gt, np.array([20, 20, 3]), radius=4.0)
    assert list(m.positives) == [1, 1, 0]
    assert m.correct[0] == [True] and m.correct[1] == [False]
    assert m.confidence[2] == []  # 3 px visible: neither right nor wrong
    s = summarize_2d(m, ["A", "B", "C"])
    assert s["ap"]["A"] == 1.0 and s["ap"]["B"] == 0.0 and np.isnan(s["ap"]["C"])
    assert s["map"] == pytest.approx(0.5) and s["precision"] == pytest.approx(0.5)

"""Corner labels from read quads: two coded squares meeting at a corner label all seven corners and name the shared
one twice; of two quads that disagree the more confident one stays, and only if confident enough alone; a code read
twice or a code the suit does not print labels nothing wrong. Studio quads are labelled from the truth with the
right rotation."""

from __future__ import annotations

import numpy as np

from mocapflow.tasks.suit.codes import code_index, label_quads
from mocapflow.tasks.suit.labels import LabelConfig, corner_labels

# Two white squares of a checkerboard meet at a corner: A's bottom-right is B's top-left (k clockwise from the
# upright top-left). Detection d sits at corner d.
SQUARES = np.array([[0, 1, 2, 3], [2, 4, 5, 6]])
CODES = {code_index("AB"): 0, code_index("7Y"): 1}
A, B = code_index("AB"), code_index("7Y")


ALONE_AT_09 = LabelConfig(solo_confidence=0.9)


def label(quads, rotation, code, confidence=(0.8, 0.7), config=ALONE_AT_09):
    return corner_labels(np.array(quads), np.array(rotation), np.array(code), np.array(confidence), CODES, SQUARES, 7,
                         config)


def test_two_squares_read_right_label_every_corner():
    # B's quad starts at its top-right corner (4): vertex i is upright corner (i + 1) mod 4
    det, named = label([[0, 1, 2, 3], [4, 5, 6, 2]], [0, 1], [A, B])
    assert det.tolist() == list(range(7))
    assert named.tolist() == [1, 1, 2, 1, 1, 1, 1]


def test_of_two_quads_that_disagree_the_more_confident_stays_if_confident_alone():
    det, _ = label([[0, 1, 2, 3], [4, 5, 6, 2]], [0, 3], [A, B])  # B read a quarter turn off: it disagrees on 2
    assert (det == -1).all()  # A alone at 0.8 is not confident enough
    det, named = label([[0, 1, 2, 3], [4, 5, 6, 2]], [0, 3], [A, B], confidence=(0.95, 0.99))
    assert det.tolist() == [-1, -1, 5, -1, 6, 2, 4]  # the misread B is more confident: its (wrong) labels stay
    det, named = label([[0, 1, 2, 3], [4, 5, 6, 2]], [0, 3], [A, B], confidence=(0.99, 0.95))
    assert det.tolist() == [0, 1, 2, 3, -1, -1, -1] and named.tolist() == [1, 1, 1, 1, 0, 0, 0]


def test_repeated_and_unknown_codes_label_nothing():
    det, _ = label([[0, 1, 2, 3], [4, 5, 6, 2]], [0, 1], [A, A])  # one code on two quads
    assert (det == -1).all()
    det, _ = label([[0, 1, 2, 3], [4, 5, 6, 2]], [0, 1], [A, code_index("QQ")], (0.95, 0.95))  # QQ not printed
    assert det.tolist() == [0, 1, 2, 3, -1, -1, -1]
    keep_repeats = LabelConfig(drop_repeated_codes=False, solo_confidence=0.9)
    det, _ = label([[0, 1, 2, 3], [4, 5, 6, 2]], [0, 1], [A, A], config=keep_repeats)
    assert det.tolist() == [-1] * 7  # the second names corners 0..3 at other detections: only the first, alone


def test_studio_quads_are_labelled_with_their_rotation():
    truth = np.array([(0, 0), (10, 0), (10, 10), (0, 10), (20, 10), (20, 20), (10, 20)], float)
    visible = np.ones(7, bool)
    quads = np.array([[0, 1, 2, 3], [4, 5, 6, 2], [5, 6, 2, 4], [0, 1, 4, 3]])
    xy = truth + 0.3
    valid, rotation, code = label_quads(xy, quads, truth, visible, SQUARES, ["AB", "7Y"])
    assert valid.tolist() == [True, True, True, False]
    assert rotation.tolist() == [0, 1, 2, -1]
    assert code.tolist() == [A, B, B, -1]
    hidden = visible.copy()
    hidden[5] = False  # a corner the view does not see: its square is no valid quad
    assert label_quads(xy, quads, truth, hidden, SQUARES, ["AB", "7Y"])[0].tolist() == [True, False, False, False]


def test_by_default_a_quad_alone_labels_nothing():
    det, _ = label([[0, 1, 2, 3]], [0], [A], (0.999,), LabelConfig())
    assert (det == -1).all()

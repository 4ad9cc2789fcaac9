"""Labels grown over the suit's grid (tasks/suit/grow.py): completion and extension from the squares read."""

from __future__ import annotations

import numpy as np
import pytest

from mocapflow.tasks.suit.grow import GrowConfig, cell_edges, far_corners, grow_labels


def _grid(rows=6, cols=7, side=30.0, tilt=0.15, bend=0.0):
    """A grid of corners seen under a mild perspective (and a bend), its cells counter-clockwise."""
    j, i = np.meshgrid(np.arange(cols + 1), np.arange(rows + 1))
    u, v = j.ravel() * side, i.ravel() * side
    w = 1 + tilt * u / (cols * side)
    xy = np.column_stack([u / w + 40 + bend * np.sin(v / 40), v / w + 30])
    at = lambda r, c: r * (cols + 1) + c  # noqa: E731
    cells = np.array([[at(r, c), at(r, c + 1), at(r + 1, c + 1), at(r + 1, c)] for r in range(rows) for c in range(cols)])
    return xy, cells


def test_labels_spread_from_one_read_square_over_the_whole_grid_and_name_every_detection_right():
    xy, cells = _grid()
    rng = np.random.default_rng(0)
    order = rng.permutation(len(xy))  # detections in any order
    detections = xy[order] + rng.normal(0, 0.3, xy.shape)
    truth = np.argsort(order)  # corner -> its detection
    start = np.full(len(xy), -1)
    start[cells[17]] = truth[cells[17]]  # one square read
    grown = grow_labels(detections, start, cells, GrowConfig(rounds=20))
    np.testing.assert_array_equal(grown, truth)
    one = grow_labels(detections, start, cells, GrowConfig(rounds=1))
    assert 4 < (one >= 0).sum() <= 4 + 8  # one round: the four squares across its edges
    assert ((one == truth) | (one < 0)).all()
    none = grow_labels(detections, start, cells, GrowConfig(rounds=1, extend=False))
    np.testing.assert_array_equal(none, start)  # no square has three corners labelled: nothing to complete


def test_a_missed_detection_is_left_unlabelled_and_a_stray_one_is_not_taken_for_it():
    xy, cells = _grid(rows=3, cols=3)
    missing = cells[4][2]  # a corner of the centre square, not detected
    keep = np.arange(len(xy)) != missing
    stray = xy[missing] + [0.45 * 30, 0.0]  # a junction half a square away (a seam, a glyph)
    detections = np.vstack([xy[keep], stray])
    truth = np.full(len(xy), -1)
    truth[keep] = np.arange(keep.sum())
    start = np.full(len(xy), -1)
    start[cells[0]] = truth[cells[0]]
    grown = grow_labels(detections, start, cells, GrowConfig(rounds=20))
    assert grown[missing] == -1 and (grown != len(detections) - 1).all()
    labelled = grown >= 0
    np.testing.assert_array_equal(grown[labelled], truth[labelled])
    # every other corner is reached around the hole but the grid's far corner: only the square with the hole has it
    assert labelled.sum() == len(xy) - 2 and not labelled[cells[8][2]]


def test_two_corners_predicted_at_one_detection_are_both_left_out():
    xy, cells = _grid(rows=1, cols=2, side=30.0, tilt=0.0)
    # cells 0 and 1 share an edge; labelling cell 0's four corners extends to cell 1's far corners (2, 5)
    squeezed = xy.copy()
    squeezed[[2, 5]] = xy[[2, 5]].mean(axis=0)  # both far corners at one place: one detection there
    detections = np.vstack([xy[[0, 1, 3, 4]], squeezed[2]])
    start = np.full(len(xy), -1)
    start[[0, 1, 3, 4]] = [0, 1, 2, 3]
    grown = grow_labels(detections, start, cells, GrowConfig(rounds=3, extend_radius=0.49))
    assert grown[2] == grown[5] == -1


def test_cell_edges_pair_the_squares_across_each_inner_edge():
    _, cells = _grid(rows=2, cols=2)
    edges = cell_edges(cells)
    assert len(edges) == 12 and sum(len(v) == 2 for v in edges.values()) == 4


def test_radii_must_stay_under_half_a_square():
    with pytest.raises(ValueError, match="a corner's neighbours are a side away"):
        GrowConfig(extend_radius=0.6)


def test_the_stage_adds_grown_labels_at_detections_with_no_quad_naming_them():
    import xarray as xr

    from mocapflow.tasks.suit.grow import grow_corner_labels

    xy, cells = _grid(rows=2, cols=2)
    n = len(xy)
    det = np.full((1, 1, n + 2), np.nan, np.float32)
    det[0, 0, :n] = xy[:, 0]
    det_y = np.full((1, 1, n + 2), np.nan, np.float32)
    det_y[0, 0, :n] = xy[:, 1]  # padded past the detections, as suit_corners is
    x, y = np.full((1, 1, n), np.nan, np.float32), np.full((1, 1, n), np.nan, np.float32)
    x[0, 0, cells[0]], y[0, 0, cells[0]] = xy[cells[0], 0], xy[cells[0], 1]
    quads = np.zeros((1, 1, n), np.int8)
    quads[0, 0, cells[0]] = 1
    coords = {"view": ["cam00"], "frame": [0]}
    dims = ("view", "frame", "corner")
    images = xr.Dataset({"cells": (("cell", "k"), cells)})
    per_detection = ("view", "frame", "detection")
    corners = xr.Dataset({"x": (per_detection, det), "y": (per_detection, det_y),
                          "logit": (per_detection, np.full(det.shape, 5.0, np.float32))}, coords=coords)
    labels = xr.Dataset({"x": (dims, x), "y": (dims, y), "quads": (dims, quads)}, coords={**coords, "corner": np.arange(n)})
    out = grow_corner_labels(images, corners, labels, GrowConfig(rounds=5, extend_radius=0.2))
    np.testing.assert_allclose(out["x"].values[0, 0], xy[:, 0], atol=1e-4)  # all nine corners labelled
    np.testing.assert_array_equal(out["quads"].values[0, 0] > 0, np.isin(np.arange(n), cells[0]))
    np.testing.assert_array_equal(labels["x"].values, x)  # the input left as it was


def test_an_extension_past_a_foreshortened_square_is_refused_not_taken_for_the_corner_after():
    """A row of squares turning away from the camera: each next square is half as wide. Extending from the first
    square lands on the third corner; the second, nearer, tells that the square was foreshortened."""
    x = np.array([0.0, 30.0, 45.0, 52.5, 60.0])  # corners along the row: sides 30, 15, 7.5, 7.5
    top, bottom = np.column_stack([x, np.zeros(5)]), np.column_stack([x, np.full(5, 30.0)])
    xy = np.vstack([top, bottom])  # corner i on top, 5 + i below
    cells = np.array([[i, i + 1, 6 + i, 5 + i] for i in range(4)])
    detections = xy.copy()
    start = np.full(10, -1)
    start[cells[0]] = cells[0]
    grown = grow_labels(detections, start, cells, GrowConfig(rounds=1, extend_radius=0.3, complete_radius=0.3))
    # 2 x (30) - 0 = 60: the fifth corner's place; the third (at 45) lies between, so nothing is named
    assert (grown[[2, 7]] == -1).all()



def test_far_corners_are_the_next_squares_corners_beside_each_edges_ends():
    _, cells = _grid(rows=2, cols=3)
    far = far_corners(cells)
    # cell 1 (row 0, column 1): corners (1, 2, 6, 5) counter-clockwise as listed; across its edge 1 -> 2 (corners
    # 2, 6: the right side) lies cell 2, whose far corners are 3 beside 2 and 7 beside 6
    np.testing.assert_array_equal(far[1, 1], [3, 7])
    np.testing.assert_array_equal(far[1, 3], [4, 0])  # across the left side (5 -> 1): 4 beside 5, 0 beside 1
    assert (far[0, 3] == -1).all() and (far[0, 0] == -1).all()  # the grid's left and top borders
    inner = far[..., 0] >= 0
    assert inner.sum() == 2 * 7  # seven inner edges, seen from both sides
    edges = cell_edges(cells)
    np.testing.assert_array_equal(far_corners(cells, edges), far)

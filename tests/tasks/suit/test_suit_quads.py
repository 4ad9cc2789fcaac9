"""Candidate quads: on a drawn checkerboard with known corners the search returns exactly its white squares, each
once and clockwise; the paper's shape filters refuse concave, sheared and stretched quads; the warp puts a quad's
vertex 0 at the crop's top-left."""

from __future__ import annotations

import numpy as np
import pytest

from mocapflow.tasks.suit import quads as qd


def checkerboard(n=6, side=20.0, origin=12.0, angle=0.3):
    """A board of n x n squares turned by ``angle``, white where i + j is even, drawn exactly (nearest pixel), and its
    (n + 1)^2 grid points. -> image, points (k, 2), white squares as sets of point indices"""
    size = int(origin * 2 + n * side * 1.5)
    c, s = np.cos(angle), np.sin(angle)
    rot = np.array([[c, -s], [s, c]])
    yy, xx = np.mgrid[0:size, 0:size].astype(float)
    centre = np.array([size / 2, size / 2])
    local = (np.stack([xx, yy], -1) - centre) @ rot + n * side / 2  # pixel -> board coordinates
    i, j = np.floor(local[..., 0] / side), np.floor(local[..., 1] / side)
    inside = (i >= 0) & (i < n) & (j >= 0) & (j < n)
    image = np.where(inside, np.where((i + j) % 2 == 0, 220, 30), 90).astype(np.uint8)
    gi, gj = np.mgrid[0:n + 1, 0:n + 1]
    grid = np.column_stack([gi.ravel(), gj.ravel()]).astype(float)
    points = (grid * side - n * side / 2) @ rot.T + centre
    index = {(int(a), int(b)): k for k, (a, b) in enumerate(grid)}
    whites = {frozenset((index[a, b], index[a + 1, b], index[a + 1, b + 1], index[a, b + 1]))
              for a in range(n) for b in range(n) if (a + b) % 2 == 0}
    return image, points, whites


def test_white_squares_found_exactly_once_clockwise():
    image, points, whites = checkerboard()
    rng = np.random.default_rng(0)
    noisy = points + rng.normal(0, 0.2, points.shape)
    quads = qd.candidate_quads(image, noisy)
    assert {frozenset(q) for q in quads.tolist()} == whites
    assert len(quads) == len(whites)  # each once
    p = noisy[quads]
    area = np.sum(p[:, :, 0] * np.roll(p[:, :, 1], -1, 1) - np.roll(p[:, :, 0], -1, 1) * p[:, :, 1], axis=1)
    assert (area > 0).all()  # clockwise with y down
    assert (quads[:, 0] == quads.min(axis=1)).all()


def test_black_squares_and_sheared_quads_fail_the_image_test():
    image, points, whites = checkerboard(angle=0.0)
    shapes = qd.corner_quads(points)
    assert len(shapes) > 2 * len(whites)  # black squares and 45-degree parallelograms pass the shape filters
    contrast = qd.edge_contrast(image, points[shapes])
    white = np.array([frozenset(q) in whites for q in shapes.tolist()])
    assert (contrast[white] > 100).all() and (contrast[~white] < 8).all()


@pytest.mark.parametrize("quad, ok", [
    ([(0, 0), (10, 0), (10, 10), (0, 10)], True),  # a square, clockwise on screen
    ([(0, 0), (0, 10), (10, 10), (10, 0)], False),  # counter-clockwise
    ([(0, 0), (10, 0), (3, 3), (0, 10)], False),  # concave
    ([(0, 0), (10, 0), (20, 10), (10, 10)], False),  # a parallelogram of 45 / 135 degrees
    ([(0, 0), (40, 0), (40, 10), (0, 10)], False),  # edges 4 : 1
    ([(0, 0), (3, 0), (3, 3), (0, 3)], False),  # too small
])
def test_shape_filters(quad, ok):
    config = qd.QuadConfig(min_angle=50.0, max_angle=130.0)
    assert bool(qd.quad_ok(np.array([quad], float), config)[0]) is ok


def test_warp_puts_vertex_zero_top_left():
    image = np.zeros((100, 100), np.uint8)
    image[20:30, 20:30] = 255  # a bright block at the quad's first vertex
    quad = np.array([[[25.0, 25.0], [75.0, 25.0], [75.0, 75.0], [25.0, 75.0]]])
    upright = qd.warp_quads(image, quad)[0]
    turned = qd.warp_quads(image, np.roll(quad, -1, axis=1))[0]  # vertex 0 now the top-right one
    lo, hi = qd.crop_square()[0].astype(int), qd.crop_square()[2].astype(int)
    assert upright[lo[1], lo[0]] == 255 and upright[hi[1], hi[0]] == 0
    assert np.array_equal(np.rot90(turned, -1), upright)  # one quarter turn of the order turns the crop


def test_bad_settings_and_images_are_refused():
    with pytest.raises(qd.QuadError, match="min_angle"):
        qd.QuadConfig(min_angle=100.0)
    with pytest.raises(qd.QuadError, match="grey"):
        qd.warp_quads(np.zeros((10, 10, 3), np.uint8), np.zeros((1, 4, 2)))


@pytest.mark.parametrize("n", [7, 60_000])  # the int64 key, and past it np.unique's own path
def test_unique_rows_are_numpys_unique_rows(n):
    rng = np.random.default_rng(3)
    rows = rng.integers(0, n, (500, 4))
    rows = np.vstack([rows, rows[::3]])[rng.permutation(667)]  # with repeats, in any order
    np.testing.assert_array_equal(qd.unique_rows(rows, n), np.unique(rows, axis=0))
    assert qd.unique_rows(np.zeros((0, 4), np.int64), n).shape == (0, 4)

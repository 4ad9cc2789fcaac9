"""The suit's pattern: unique codes, corner keys consistent across neighbouring squares, corners where the print
puts them, squares of one size on the body."""

from __future__ import annotations

import numpy as np
import pytest

from mocapflow.tasks.shared.mesh_body import Phenotype, mesh_body
from mocapflow.tasks.suit import pattern as pt


@pytest.fixture(scope="module")
def body():
    return mesh_body(Phenotype())


@pytest.fixture(scope="module")
def suits(body):
    return {name: pt.make_suit(body, size) for name, size in pt.SUITS.items()}


def test_codes_are_unique_two_letter_words_of_the_alphabet(suits):
    for suit in suits.values():
        assert len(set(suit.codes)) == len(suit.codes) <= pt.MAX_CODES
        assert all(len(c) == 2 and set(c) <= set(pt.ALPHABET) for c in suit.codes)
    assert not {"O", "I", "0", "9"} & set(pt.ALPHABET)  # no symbol that reads the same turned


def test_suit_sizes_hold_about_the_papers_corner_counts(suits):
    assert 1350 <= suits["medium"].n_corners <= 1500
    assert 1050 <= suits["small"].n_corners <= 1200
    assert len(suits["medium"].codes) > len(suits["small"].codes)


def test_quad_vertices_run_clockwise_from_the_upright_top_left(suits):
    suit = suits["medium"]
    g = suit.corner_grid[suit.square_corners]  # (square, 4, 2) grid (i along u, j along v up)
    np.testing.assert_array_equal(g[:, 1] - g[:, 0], np.tile([1, 0], (len(g), 1)))  # top-left -> top-right
    np.testing.assert_array_equal(g[:, 2] - g[:, 1], np.tile([0, -1], (len(g), 1)))  # -> bottom-right (down)
    np.testing.assert_array_equal(g[:, 3] - g[:, 2], np.tile([-1, 0], (len(g), 1)))  # -> bottom-left
    assert ((g[:, 3].sum(axis=1)) % 2 == 0).all()  # white squares: i + j of the bottom-left corner even


def test_a_corner_between_two_coded_squares_has_two_consistent_keys(suits):
    suit = suits["medium"]
    keys = suit.corner_keys()
    assert max(len(k) for k in keys) == 2 and min(len(k) for k in keys) == 1
    two = [k for k in keys if len(k) == 2]
    assert len(two) > suit.n_corners // 2
    for (code_a, ka), (code_b, kb) in two:
        # Coded squares touch only diagonally: top-left meets bottom-right, top-right meets bottom-left.
        assert {ka, kb} in ({0, 2}, {1, 3})
        a, b = suit.code_index[code_a], suit.code_index[code_b]
        assert len(set(suit.square_corners[a]) & set(suit.square_corners[b])) == 1
    for (code, k), c in suit.keys.items():
        assert suit.square_corners[suit.code_index[code], k] == c


def test_squares_are_one_size_on_the_rest_body_like_a_printed_garment(body, suits):
    for suit in suits.values():
        q = body.vertices[body.faces[suit.corner_face]]  # (corner, 3, 3)
        u, v = suit.corner_bary[:, :1, None], suit.corner_bary[:, 1:, None]
        rest = ((1 - u - v) * q[:, :1] + u * q[:, 1:2] + v * q[:, 2:])[:, 0][suit.square_corners]  # (square, 4, 3)
        side = np.sqrt(0.5 * np.linalg.norm(np.cross(rest[:, 2] - rest[:, 0], rest[:, 1] - rest[:, 3]), axis=1))
        assert side.max() <= 1.5 * side.min()  # the bound: the largest square at most 1.5 x the smallest
        assert np.median(side) == pytest.approx(suit.size.square_m, rel=0.05)
        edges = np.linalg.norm(rest - np.roll(rest, 1, axis=1), axis=2)
        assert edges.min() >= suit.size.square_m / suit.size.size_band - 1e-9
        assert edges.max() <= suit.size.square_m * suit.size.size_band + 1e-9


def test_every_panel_carries_codes_and_no_square_or_cell_spans_two_panels(suits):
    from mocapflow.tasks.suit.panels import PANELS
    suit = suits["medium"]
    panel_of_corner = suit.face_panel[suit.corner_face]
    assert (panel_of_corner >= 0).all()
    square_panels = panel_of_corner[suit.square_corners]  # (square, 4)
    assert (square_panels == square_panels[:, :1]).all()
    assert set(square_panels[:, 0]) == set(range(len(PANELS)))
    cell_panels = panel_of_corner[suit.cells]
    assert (cell_panels == cell_panels[:, :1]).all()


def test_corners_sit_on_the_body_where_the_print_puts_them(body, suits):
    suit = suits["small"]
    tri = suit.face_uv[suit.corner_face].astype(np.float64)  # (corner, 3, 2)
    u, v = suit.corner_bary[:, :1], suit.corner_bary[:, 1:]
    uv = (1 - u - v) * tri[:, 0] + u * tri[:, 1] + v * tri[:, 2]
    np.testing.assert_allclose(uv, suit.corner_uv, atol=1e-9)
    assert (suit.corner_bary >= -1e-9).all() and (suit.corner_bary.sum(axis=1) <= 1 + 1e-9).all()
    assert body.skin[suit.corner_face].all()
    g = suit.corner_grid[suit.cells]  # grid squares: four neighbouring grid points
    assert (np.abs(np.diff(g, axis=1, append=g[:, :1])).sum(axis=2) == 1).all()


def test_the_texture_prints_the_checkerboard_and_the_codes(body, suits):
    suit = suits["small"]
    res = pt.TEXELS
    tex = pt.texture(suit, res)
    s, off = suit.size.square_uv, np.zeros(2)

    def at(u, v):
        return tex[int((1 - v) * res), int(u * res)]

    for square in range(0, len(suit.codes), 37):
        i, j = suit.corner_grid[suit.square_corners[square, 3]]  # bottom-left of a coded (white) square
        assert at((i + 0.1) * s + off[0], (j + 0.1) * s + off[1]) == pytest.approx(pt.WHITE, abs=0.02)
        inner = tex[int((1 - (j + 0.75) * s - off[1]) * res):int((1 - (j + 0.25) * s - off[1]) * res),
                    int(((i + 0.15) * s + off[0]) * res):int(((i + 0.85) * s + off[0]) * res)]
        assert inner.min() < 0.3  # the code's ink
    cells = suit.corner_grid[suit.cells[:, 0]]  # each grid square's (i, j) corner
    for i, j in cells[cells.sum(axis=1) % 2 == 1][::29]:  # black squares
        assert at((i + 0.5) * s + off[0], (j + 0.5) * s + off[1]) == pytest.approx(pt.BLACK, abs=0.02)


def test_bad_sizes_are_refused(body):
    with pytest.raises(pt.PatternError, match="two-letter codes"):
        pt.make_suit(body, pt.SuitSize("tiny", 0.02, 12))
    with pytest.raises(pt.PatternError, match="0.01-0.1 m"):
        pt.make_suit(body, pt.SuitSize("huge", 0.5, 40))

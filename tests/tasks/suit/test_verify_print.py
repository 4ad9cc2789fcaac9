"""Readings checked against the print (tasks/suit/verify.py) on a studio image: the small suit on the reference body,
one 384 x 512 grey camera (about 30 px a square, as in the benchmarks), corners at their true pixels. A right code
is kept, a planted wrong code is refused or corrected to the true one, a right grown label is kept and planted
wrong ones (the corner named at its neighbour's pixel, or half a square off) are dropped; the grid's coordinates
come from the cells alone."""

from __future__ import annotations

import numpy as np
import pytest

from mocapflow.tasks.suit import verify as vf


@pytest.fixture(scope="module")
def studio():
    """One studio view of the small suit on the reference body (the suit is sewn once: about 15 s)."""
    from mocapflow.systems.suit.film import reference_suit
    from mocapflow.tasks.shared.mesh_body import Phenotype, mesh_body
    from mocapflow.tasks.suit import takes

    suit = reference_suit("small")
    body = mesh_body(Phenotype())
    cameras = takes.SuitCameras(count=1, width=384, height=512, view_height_m=0.6, heights=(1.2, 1.2),
                                target=(0.0, 0.0, 1.2))
    rig = takes.suit_rig(body, suit, cameras, takes.SuitLook(), 5)
    shot = takes.film(rig, body.vertices[None], range(1))
    return suit, shot.image[0, 0], shot.corners2d[0, 0].astype(np.float64), shot.readable[0, 0]


def _readable_squares(suit, readable, n):
    """The first ``n`` coded squares with all four corners readable."""
    whole = np.flatnonzero(readable[suit.square_corners].all(axis=1))
    assert len(whole) >= n, f"only {len(whole)} readable squares in the view"
    return whole[:n]


def test_a_right_code_is_kept_and_a_planted_wrong_one_refused_or_corrected(studio):
    suit, image, xy, readable = studio
    config = vf.VerifyCodesConfig()
    canvas = config.canvas
    templates = vf.code_templates(tuple(suit.codes), vf.print_texels("small", canvas), canvas.square_px, canvas.blur)
    squares = _readable_squares(suit, readable, 12)
    rotation = np.arange(len(squares)) % 4  # quad vertex i is the square's corner (i + r) mod 4
    points = np.stack([np.roll(xy[suit.square_corners[s]], -r, axis=0) for s, r in zip(squares, rotation)])
    patches = vf.rectify_quads(image, points, canvas)

    right = vf.check_codes(patches, squares, rotation, templates, config)
    assert (right.verdict == 1).mean() >= 0.9, right
    kept = right.verdict == 1
    np.testing.assert_array_equal(right.code[kept], squares[kept])
    np.testing.assert_array_equal(right.rotation[kept], rotation[kept])
    assert np.median(right.read_ncc) > 0.85

    wrong_square = (squares + 7) % len(suit.codes)  # another printed code
    wrong = vf.check_codes(patches, wrong_square, rotation, templates, config)
    assert (wrong.verdict != 1).all()  # never kept
    fixed = wrong.verdict == 2
    np.testing.assert_array_equal(wrong.code[fixed], squares[fixed])  # corrected to the print's code
    np.testing.assert_array_equal(wrong.rotation[fixed], rotation[fixed])
    assert (wrong.code[~fixed] == -1).all()
    turned = vf.check_codes(patches, squares, (rotation + 1) % 4, templates, config)  # read a quarter turn off
    assert (turned.verdict != 1).all()
    assert (turned.code[turned.verdict == 2] == squares[turned.verdict == 2]).all()
    lacking = vf.check_codes(patches, np.full(len(squares), -1), rotation, templates, config)  # a code not printed
    assert (lacking.verdict != 1).all()


def test_the_grid_is_recovered_from_the_cells(studio):
    suit = studio[0]
    grid = vf.suit_grid(suit.cells, suit.square_corners, suit.n_corners)
    assert (grid.piece >= 0).all()
    for c in range(0, suit.n_corners, 37):  # differences of grid coordinates are the print's, piece by piece
        same = grid.piece == grid.piece[c]
        np.testing.assert_array_equal(grid.ij[same] - grid.ij[c], suit.corner_grid[same] - suit.corner_grid[c])
    assert len(grid.square_at) == len(suit.codes)


def test_a_right_grown_label_is_kept_and_planted_wrong_ones_dropped(studio):
    suit, image, xy, readable = studio
    grid = vf.suit_grid(suit.cells, suit.square_corners, suit.n_corners)
    labels = np.where(readable[:, None], xy, np.nan)
    config = vf.VerifyLabelsConfig()
    texels = vf.print_texels("small", config.canvas)
    # corners with readable neighbours one square on either side along the grid's i axis
    inner = [c for c in np.flatnonzero(readable)
             if all(readable[grid.corner_at.get((int(grid.piece[c]), int(grid.ij[c, 0] + a), int(grid.ij[c, 1] + b)),
                                                c)] for a in (-1, 0, 1) for b in (-1, 0, 1))]
    assert len(inner) >= 10
    chosen = np.array(inner[::max(1, len(inner) // 10)][:10])
    check = np.zeros(suit.n_corners, bool)
    check[chosen] = True

    keep, scores = vf.check_labels(image, labels, check, grid, tuple(suit.codes), texels, config)
    assert keep[chosen].mean() >= 0.9, scores[chosen]  # right grown labels stay
    assert keep[readable & ~check].all()  # unchecked labels are left alone
    assert np.median(scores[chosen, 1]) > 0.85 and np.median(scores[chosen, 2]) < 1.5

    moved = labels.copy()  # each named at the pixel of the corner one square on (its neighbour along i)
    for c in chosen:
        moved[c] = xy[grid.corner_at[(int(grid.piece[c]), int(grid.ij[c, 0] + 1), int(grid.ij[c, 1]))]]
    keep, scores = vf.check_labels(image, moved, check, grid, tuple(suit.codes), texels, config)
    assert not keep[chosen].any(), scores[chosen]
    # the checker's colours are swapped one square on: the corner's NCC is negative (measured -0.47 to 0.37, median
    # -0.37, against 0.85 and more where right)
    assert np.median(scores[chosen, 1]) < 0 and (scores[chosen, 1] < config.min_centre_ncc).all(), scores[chosen]

    shifted = labels.copy()  # half a square off the corner, inside a square
    side = np.linalg.norm(xy[suit.square_corners[:, 0]] - xy[suit.square_corners[:, 1]], axis=1)
    half = 0.5 * np.median(side[readable[suit.square_corners].all(axis=1)])
    shifted[chosen] += (half, half)
    keep, _ = vf.check_labels(image, shifted, check, grid, tuple(suit.codes), texels, config)
    assert not keep[chosen].any()


def test_settings_out_of_range_are_refused_with_the_fix():
    with pytest.raises(vf.VerifyError, match="square_px"):
        vf.PrintCanvas(square_px=30)
    with pytest.raises(vf.VerifyError, match="agree_ncc"):
        vf.VerifyCodesConfig(agree_ncc=2.0)
    with pytest.raises(vf.VerifyError, match="centre_px"):
        vf.VerifyLabelsConfig(centre_px=40)
    with pytest.raises(vf.VerifyError, match="grey"):
        vf.rectify_quads(np.zeros((4, 4, 3), np.uint8), np.zeros((1, 4, 2)))

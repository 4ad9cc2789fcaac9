"""Hole filling (Chen et al. 2021, §5, Eq. 8): known displacement fields on known corner meshes, points hidden and
filled back; the KKT and reduced solves; windows; skinning into the rest pose and back."""

import numpy as np
import pytest
import scipy.sparse as sp
from scipy.spatial.transform import Rotation

from mocapflow.tasks.suit.fill import (FillConfig, FillError, blend_weights, cotangent_laplacian, fill_sequence,
                                       quad_triangles, repose, skinning_transforms, solve_window, temporal_laplacian,
                                       unpose, windows)


def grid(rows: int, cols: int, spacing: float = 0.02, jitter: float = 0.0, seed: int = 0):
    """A flat rows x cols grid of corners (z = 0) and its quads, cyclic; in-plane jitter as a fraction of spacing."""
    i, j = np.meshgrid(np.arange(rows), np.arange(cols), indexing="ij")
    rest = np.column_stack([i.ravel() * spacing, j.ravel() * spacing, np.zeros(rows * cols)])
    rest[:, :2] += np.random.default_rng(seed).uniform(-jitter, jitter, (rows * cols, 2)) * spacing
    k = (i * cols + j)[:-1, :-1].ravel()
    cells = np.column_stack([k, k + cols, k + cols + 1, k + 1])
    return rest, cells


def ring(rows: int, cols: int) -> np.ndarray:
    """Each grid corner's distance in steps from the grid's border.  -> (corner,)"""
    i, j = np.meshgrid(np.arange(rows), np.arange(cols), indexing="ij")
    return np.minimum.reduce([i, j, rows - 1 - i, cols - 1 - j]).ravel()


def linear_field(rest: np.ndarray, frames: int, seed: int = 1) -> np.ndarray:
    """A displacement affine in rest position and in time.  -> (frame, corner, 3)"""
    rng = np.random.default_rng(seed)
    a, b, c = rng.normal(0, 0.1, (3, 3)), rng.normal(0, 1e-4, 3), rng.normal(0, 0.005, 3)
    t = np.arange(frames)[:, None, None]
    return (rest @ a.T)[None] + t * b + c


def smooth_field(rest: np.ndarray, frames: int) -> np.ndarray:
    """A smooth displacement: quadratic in rest position, slow in time, a few mm.  -> (frame, corner, 3)"""
    t = np.arange(frames)[:, None] / 100.0  # (frame, 1)
    x, y = rest[:, 0][None], rest[:, 1][None]
    return 0.003 * np.stack([np.sin(t + 2 * x) + 10 * x * y, np.cos(0.7 * t) * (1 + 5 * y ** 2),
                             np.sin(1.3 * t + 3 * y) * x], -1)


def hide(truth: np.ndarray, hidden: np.ndarray) -> np.ndarray:
    return np.where(hidden[..., None], np.nan, truth)


# --- the corner mesh -------------------------------------------------------------------------------------------------


def test_cotangent_laplacian_of_a_grid_has_unit_weights_and_kills_linear_fields():
    rest, cells = grid(5, 6, jitter=0.1)
    lap = cotangent_laplacian(rest, cells)
    assert lap.shape == (30, 30) and abs(lap - lap.T).max() < 1e-12
    np.testing.assert_allclose(lap @ np.ones(30), 0.0, atol=1e-12)  # rows sum to zero
    assert (lap - sp.diags(lap.diagonal())).max() <= 0.0  # non-negative edge weights
    interior = ring(5, 6) >= 1
    np.testing.assert_allclose((lap @ rest)[interior], 0.0, atol=1e-12)  # flat mesh: linear functions harmonic
    straight = cotangent_laplacian(*grid(3, 3))  # square cells cut in two right triangles: weight 1/2 + 1/2 or 0
    assert straight[4, 1] == pytest.approx(-1.0) and straight[4, 4] == pytest.approx(4.0)


def test_quads_split_along_the_shorter_diagonal():
    rest = np.array([[0, 0, 0], [2, 0, 0], [2.5, 1, 0], [0, 1, 0]], float)  # diagonal b-d shorter than a-c
    tris = quad_triangles(rest, np.array([[0, 1, 2, 3]]))
    assert {tuple(sorted(t)) for t in tris} == {(0, 1, 3), (1, 2, 3)}


def test_degenerate_and_obtuse_triangles_give_finite_non_negative_weights():
    rest, cells = grid(3, 3)
    rest[4] = rest[1]  # a corner on top of another: zero-area triangles
    rest[5] = [0.04, 0.02, 0.05]  # a spike: obtuse angles
    lap = cotangent_laplacian(rest, cells).toarray()
    assert np.isfinite(lap).all() and (lap - np.diag(np.diag(lap)) <= 0).all()
    np.testing.assert_allclose(lap.sum(1), 0.0, atol=1e-9)


def test_corners_in_no_cell_have_no_spatial_term():
    rest, cells = grid(3, 3)
    rest = np.vstack([rest, [[1.0, 1.0, 1.0]]])
    lap = cotangent_laplacian(rest, cells)
    assert lap.shape == (10, 10) and lap[9].nnz == 0 and lap[:, 9].nnz == 0


def test_temporal_laplacian_is_the_second_difference():
    d2 = temporal_laplacian(5)
    assert d2.shape == (3, 5)
    np.testing.assert_allclose(d2 @ np.arange(5.0) ** 2, 2.0)  # (t+1)^2 - 2 t^2 + (t-1)^2 = 2
    np.testing.assert_allclose(d2 @ (3 * np.arange(5.0) + 1), 0.0)


# --- one window ------------------------------------------------------------------------------------------------------


def test_solve_keeps_observed_points_and_recovers_a_linear_field_exactly():
    rest, cells = grid(9, 10, jitter=0.1)
    lap = cotangent_laplacian(rest, cells)
    truth = linear_field(rest, 40)
    hidden = np.zeros(truth.shape[:2], bool)
    inner = np.flatnonzero(ring(9, 10) >= 2)
    hidden[5:30, inner[::2]] = True  # every other inner corner for 25 frames
    hidden[:, inner[7]] = True  # one never observed in the window: filled through the spatial term
    out = solve_window(hide(truth, hidden), lap, FillConfig())
    np.testing.assert_array_equal(out[~hidden], truth[~hidden])  # the hard constraints, exactly
    np.testing.assert_allclose(out[hidden], truth[hidden], atol=1e-9)


def test_kkt_and_reduced_solves_agree():
    rest, cells = grid(7, 8, jitter=0.2, seed=3)
    lap = cotangent_laplacian(rest, cells)
    truth = smooth_field(rest, 30)
    hidden = np.random.default_rng(2).random(truth.shape[:2]) < 0.3
    reduced = solve_window(hide(truth, hidden), lap, FillConfig(method="reduced"))
    kkt = solve_window(hide(truth, hidden), lap, FillConfig(method="kkt"))
    np.testing.assert_allclose(kkt, reduced, rtol=0, atol=1e-9)
    np.testing.assert_array_equal(kkt[~hidden], truth[~hidden])


def test_solve_fills_a_smooth_field_on_a_curved_sheet():
    rest, cells = grid(14, 14)
    angle = rest[:, 0] / 0.2  # bend the sheet round a cylinder of radius 0.2 m
    rest = np.column_stack([0.2 * np.sin(angle), rest[:, 1], 0.2 * (1 - np.cos(angle))])
    lap = cotangent_laplacian(rest, cells)
    truth = smooth_field(rest, 60)
    rng = np.random.default_rng(4)
    hidden = rng.random(truth.shape[:2]) < 0.3
    patch = np.linalg.norm(rest - rest[7 * 14 + 7], axis=1) < 0.05  # a hole ~5 cm wide for 20 frames
    hidden[20:40, patch] = True
    out = solve_window(hide(truth, hidden), lap, FillConfig())
    error = np.linalg.norm(out - truth, axis=-1)[hidden]
    assert np.median(error) < 1e-5 and error.max() < 2e-4  # field ~3 mm: recovered to 0.2 mm at worst
    assert np.median(np.linalg.norm(truth, axis=-1)) > 1e-3  # (the field is not trivially small)


def test_parts_observed_in_fewer_than_two_frames_stay_nan():
    rest, cells = grid(4, 4)
    rest = np.vstack([rest, [[1.0, 1.0, 1.0]], [[2.0, 1.0, 1.0]]])  # two corners in no cell
    lap = cotangent_laplacian(rest, cells)
    truth = linear_field(rest, 10)
    hidden = np.zeros(truth.shape[:2], bool)
    hidden[:, 16] = True
    hidden[:, 16][[2, 7]] = False  # corner 16: seen twice, filled along its own line in time
    hidden[:, 17] = True
    hidden[:, 17][4] = False  # corner 17: seen once, its drift is free
    out = solve_window(hide(truth, hidden), lap, FillConfig())
    np.testing.assert_allclose(out[:, 16], truth[:, 16], atol=1e-9)
    assert np.isnan(out[:, 17][hidden[:, 17]]).all() and (out[4, 17] == truth[4, 17]).all()
    np.testing.assert_allclose(out[:, :16], truth[:, :16], atol=1e-12)
    assert np.isnan(solve_window(np.full((10, 18, 3), np.nan), lap, FillConfig())).all()  # nothing observed


def test_windows_of_one_or_two_frames_fill_through_space_alone():
    rest, cells = grid(6, 6)
    lap = cotangent_laplacian(rest, cells)
    truth = np.broadcast_to([[[0.002, -0.001, 0.003]], [[0.001, 0.0, 0.002]]], (2, 36, 3))  # a shift per frame
    hidden = np.zeros((2, 36), bool)
    hidden[:, ring(6, 6) >= 1] = True  # only the border seen
    for frames in (1, 2):
        out = solve_window(hide(truth[:frames], hidden[:frames]), lap, FillConfig())
        np.testing.assert_allclose(out, truth[:frames], atol=1e-12)
    hidden[1] = True  # the second frame unseen: nothing pins it
    out = solve_window(hide(truth, hidden), lap, FillConfig())
    assert np.isnan(out[hidden]).all() and (out[~hidden] == truth[~hidden]).all()
    short, observed = fill_sequence(hide(truth, hidden), lap, FillConfig(window=150, overlap=0))
    assert np.isnan(short[1]).all() and observed[0].sum() == 20


# --- windows ---------------------------------------------------------------------------------------------------------


def test_windows_cover_the_take_and_blend_weights_sum_to_one():
    config = FillConfig(window=150, overlap=50)
    for frames in (1, 149, 150, 151, 300, 333):
        spans = windows(frames, config)
        assert spans[0][0] == 0 and spans[-1][1] == frames
        assert all(b[0] == a[1] - 50 for a, b in zip(spans, spans[1:]))
        total = np.zeros(frames)
        for (start, stop), w in zip(spans, blend_weights(spans)):
            assert stop - start <= 150 and (w > 0).all()
            total[start:stop] += w
        np.testing.assert_allclose(total, 1.0)
    assert windows(300, config) == [(0, 150), (100, 250), (200, 300)]


def test_windows_blend_without_a_seam():
    rest, cells = grid(10, 10)
    lap = cotangent_laplacian(rest, cells)
    centre = rest[55]
    bump = np.exp(-((rest - centre) ** 2).sum(1) / (2 * 0.03 ** 2)) * np.sin(np.arange(300.0)[:, None] / 15)
    truth = smooth_field(rest, 300) + 0.003 * bump[..., None] * np.array([0.0, 0.0, 1.0])  # a breathing bump
    hidden = np.random.default_rng(5).random(truth.shape[:2]) < 0.2
    patch = np.flatnonzero(np.linalg.norm(rest - centre, axis=1) < 0.05)
    hidden[80:190, patch] = True  # the bump hidden across the first two windows' overlap (100-150)
    windowed, observed = fill_sequence(hide(truth, hidden), lap, FillConfig())
    single, _ = fill_sequence(hide(truth, hidden), lap, FillConfig(window=300, overlap=0))
    np.testing.assert_array_equal(observed, ~hidden)
    np.testing.assert_array_equal(windowed[observed], truth[observed])
    assert np.abs(single - truth)[80:190, patch].max() > 1e-3  # a hole the fill does not guess (a hard case) ...
    assert np.abs(windowed - single).max() < 1e-5  # ... where windows still match one solve to 10 micrometres
    curvature = [np.abs(np.diff(x[90:160, patch], 2, axis=0)).max() for x in (windowed, single)]
    assert curvature[0] < curvature[1] * 1.01  # no kink where the windows meet


def test_fill_sequence_leaves_an_unobservable_window_nan():
    rest, cells = grid(4, 4)
    lap = cotangent_laplacian(rest, cells)
    truth = np.broadcast_to(0.01 + 1e-4 * np.arange(260.0)[:, None, None], (260, 16, 3))  # a uniform drift,
    # which Eq. (8) extrapolates exactly (a linear field would not be: L's rows at the border are not zero for it)
    hidden = np.zeros(truth.shape[:2], bool)
    hidden[130:] = True  # windows 0-150, 100-250, 200-260: the last one sees nothing
    filled, observed = fill_sequence(hide(truth, hidden), lap, FillConfig())
    assert np.isnan(filled[250:]).all() and not observed[130:].any()
    np.testing.assert_allclose(filled[:250], truth[:250], atol=1e-9)  # 200-249 from the middle window alone


# --- skinning --------------------------------------------------------------------------------------------------------


def bones(frames: int, count: int, seed: int = 6) -> np.ndarray:
    rng = np.random.default_rng(seed)
    out = np.tile(np.eye(4), (frames, count, 1, 1))
    out[..., :3, :3] = Rotation.from_rotvec(rng.normal(0, 0.4, (frames * count, 3))).as_matrix().reshape(
        frames, count, 3, 3)
    out[..., :3, 3] = rng.normal(0, 0.5, (frames, count, 3))
    return out


def test_unpose_inverts_repose():
    rng = np.random.default_rng(7)
    weights = rng.random((20, 4)) ** 3
    weights /= weights.sum(1, keepdims=True)
    transforms = skinning_transforms(weights, bones(5, 4))
    rest = rng.normal(0, 0.3, (20, 3))
    posed = repose(np.broadcast_to(rest, (5, 20, 3)), transforms)
    np.testing.assert_allclose(unpose(posed, transforms), np.broadcast_to(rest, (5, 20, 3)), atol=1e-12)
    np.testing.assert_allclose(repose(unpose(posed, transforms), transforms), posed, atol=1e-12)
    one_bone = skinning_transforms(np.eye(4)[[2]], bones(5, 4))  # a single weight: that bone's transform
    np.testing.assert_allclose(one_bone[:, 0], bones(5, 4)[:, 2])
    posed[1, 3] = np.nan
    assert np.isnan(unpose(posed, transforms)[1, 3]).all() and np.isfinite(unpose(posed, transforms)[0]).all()


# --- bad inputs ------------------------------------------------------------------------------------------------------


def test_bad_inputs_are_refused():
    rest, cells = grid(3, 3)
    lap = cotangent_laplacian(rest, cells)
    with pytest.raises(FillError, match="window"):
        FillConfig(window=50, overlap=50)
    with pytest.raises(FillError, match="temporal_weight"):
        FillConfig(temporal_weight=0.0)
    with pytest.raises(FillError, match="method"):
        FillConfig(method="cholesky")
    bad = rest.copy()
    bad[2, 1] = np.nan
    with pytest.raises(FillError, match="not finite"):
        cotangent_laplacian(bad, cells)
    with pytest.raises(FillError, match=r"\(corner, 3\)"):
        cotangent_laplacian(rest[:, :2], cells)
    with pytest.raises(FillError, match="cells index"):
        cotangent_laplacian(rest, cells + 5)
    with pytest.raises(FillError, match=r"\(cell, 4\)"):
        cotangent_laplacian(rest, cells[:, :3])
    with pytest.raises(FillError, match=r"\(frame, corner, 3\)"):
        fill_sequence(np.zeros((4, 9)), lap)
    with pytest.raises(FillError, match="Laplacian"):
        fill_sequence(np.zeros((4, 8, 3)), lap)
    with pytest.raises(FillError, match="no corner is observed"):
        fill_sequence(np.full((4, 9, 3), np.nan), lap)
    with pytest.raises(FillError, match="same bones"):
        skinning_transforms(np.ones((9, 3)), bones(2, 4))
    with pytest.raises(FillError, match="unpose takes"):
        unpose(np.zeros((2, 8, 3)), np.zeros((2, 9, 4, 4)))
    with pytest.raises(FillError, match="singular"):
        unpose(np.zeros((2, 9, 3)), np.zeros((2, 9, 4, 4)))

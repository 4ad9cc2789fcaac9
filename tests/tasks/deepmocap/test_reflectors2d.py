"""Greedy inference: peaks, the OFF line integral (Eq. 7-8), fused confidence (Eq. 9) and each filtering rule."""

from dataclasses import replace

import numpy as np
import pytest
import xarray as xr

from mocapflow.tasks.deepmocap import reflectors2d as r2d
from mocapflow.tasks.deepmocap import targets


def test_line_integral_is_one_along_the_field_and_zero_across():
    field = np.zeros((20, 20, 2))
    field[..., 0] = 1.0  # unit motion along +x everywhere
    assert r2d.line_integral(field, np.array([3.0, 5.0]), np.array([12.0, 5.0]), 10) == pytest.approx(1.0)
    assert r2d.line_integral(field, np.array([5.0, 3.0]), np.array([5.0, 12.0]), 10) == pytest.approx(0.0, abs=1e-12)
    assert r2d.line_integral(field, np.array([12.0, 5.0]), np.array([3.0, 5.0]), 10) == pytest.approx(-1.0)
    diagonal = r2d.line_integral(field, np.array([2.0, 2.0]), np.array([8.0, 8.0]), 10)
    assert diagonal == pytest.approx(np.sqrt(0.5))
    assert r2d.line_integral(field, np.array([2.0, 2.0]), np.array([2.0, 2.0]), 10) == 0.0


def test_line_integrals_of_every_pair_equal_the_single_integrals():
    rng = np.random.default_rng(0)
    field = rng.normal(size=(16, 20, 2))
    starts = np.array([[3.0, 4.0], [10.5, 7.25], [5.0, 5.0]])
    ends = np.array([[12.0, 9.0], [5.0, 5.0], [-2.0, 30.0]])  # the second coincides with a start; the third leaves
    table = r2d.line_integrals(field, starts, ends, 10)
    assert table.shape == (3, 3) and table[2, 1] == 0.0
    for i, start in enumerate(starts):
        for j, end in enumerate(ends):
            assert table[i, j] == pytest.approx(r2d.line_integral(field, start, end, 10), abs=1e-12)


def test_line_integrals_of_a_stack_equal_each_fields_own():
    rng = np.random.default_rng(1)
    fields = rng.normal(size=(3, 16, 20, 2))
    starts = [rng.uniform(-2, 22, (2, 2)), np.empty((0, 2)), rng.uniform(0, 16, (3, 2))]
    ends = [rng.uniform(-2, 22, (3, 2)), rng.uniform(0, 16, (2, 2)), rng.uniform(0, 16, (1, 2))]
    tables = r2d.line_integral_sets(fields, starts, ends, 10)
    assert [t.shape for t in tables] == [(2, 3), (0, 2), (3, 1)]
    for field, a, b, table in zip(fields, starts, ends, tables):
        np.testing.assert_array_equal(table, r2d.line_integrals(field, a, b, 10))  # same numbers, not just close
    assert r2d.line_integral_sets(fields[:0], [], [], 10) == []


def test_fused_confidence_of_eq9():
    assert r2d.fuse(0.5, 1.0) == pytest.approx(1.0)
    assert r2d.fuse(0.5, 0.0) == pytest.approx(0.5)
    assert r2d.fuse(0.6, 0.5) == pytest.approx(0.8)
    assert r2d.fuse(0.6, -0.7) == pytest.approx(0.6)  # against the motion: no bonus, no penalty
    np.testing.assert_allclose(r2d.fuse(np.array([0.5, 0.6, 0.6]), np.array([1.0, 0.5, -0.7])), [1.0, 0.8, 0.6])


def test_peaks_are_local_maxima_refined_to_sub_cell():
    c = np.zeros((12, 12))
    c[4, 6], c[4, 7] = 0.8, 0.8 * 0.5  # a peak leaning right
    c[9, 2] = 0.3
    cells, values = r2d.peaks(c, threshold=0.1, max_n=5)
    np.testing.assert_allclose(values, [0.8, 0.3])
    assert cells[0, 1] == pytest.approx(4.0) and 6.0 < cells[0, 0] < 6.5
    np.testing.assert_allclose(cells[1], [2.0, 9.0])
    assert len(r2d.peaks(c, threshold=0.5, max_n=5)[1]) == 1


def test_peaks_of_a_stack_are_each_maps_local_maxima():
    rng = np.random.default_rng(1)
    stack = rng.uniform(size=(4, 10, 12)).astype(np.float32)
    stack[2] = 0.0  # a map without peaks
    for (cells, values), c in zip(r2d.peak_sets(stack, 0.3, 3), stack):
        padded = np.pad(c, 1)
        maxima = sorted(((c[y, x], x, y) for y in range(10) for x in range(12)
                         if c[y, x] >= 0.3 and c[y, x] == padded[y:y + 3, x:x + 3].max()), reverse=True)[:3]
        np.testing.assert_array_equal(values, [m[0] for m in maxima])
        assert np.abs(cells - np.reshape([m[1:] for m in maxima], (-1, 2))).max(initial=0) < 1  # refined near its cell
    assert r2d.peak_sets(stack, 0.3, 3)[2][0].shape == (0, 2)


def _blobs(shape=(60, 80)):
    blob_id = np.zeros(shape, np.uint16)
    blob_id[10:12, 20:22] = 1  # 4 px: too small for b_min = 5
    blob_id[30:33, 40:43] = 2  # 9 px, centre (41, 31)
    blob_id[30:33, 50:60] = 3  # two touching reflectors' 30 px region
    return blob_id, np.array([4, 9, 30])


RULES = r2d.GreedyConfig(b_min=5, min_distance_px=3.0, snap_px=6.0, region_radius_px=4.0, split_px=0.0, c_min=0.2,
                         recover_snap_px=0.0)
GREEDY = replace(RULES, peak_threshold=0.1, max_candidates=3, line_samples=10, split_neighbours_m=0.0,
                 recover_neighbours_m=0.0)


def test_filtering_rules():
    blob_id, area = _blobs()
    xy = np.array([[21.0, 11.0],  # on a 4 px region: below b_min
                   [43.5, 30.0],  # near the 9 px region: its centre
                   [15.0, 50.0],  # far from any region
                   [51.0, 31.0],  # left part of the shared region
                   [58.0, 31.0],  # right part of the shared region
                   [41.5, 31.5],  # within 3 px of estimate 1 but less confident
                   [41.0, 31.0]])  # ... and one below c_min
    conf = np.array([0.9, 0.8, 0.9, 0.7, 0.7, 0.6, 0.1])
    out, kept_conf, size, _ = r2d.filter_frame(xy, conf, blob_id, area, RULES)
    assert np.isnan(out[0]).all() and size[0] == 0  # b_min
    np.testing.assert_allclose(out[1], [41.0, 31.0])  # the region's centre, sub-pixel
    assert size[1] == 9 and kept_conf[1] == pytest.approx(0.8)
    assert np.isnan(out[2]).all()  # not on a reflector region
    assert out[3][0] < 54 and out[4][0] > 54  # the shared region is split by proximity
    assert size[3] == size[4] == 30
    assert np.isnan(out[5]).all()  # closer than 3 px to a more confident estimate
    assert np.isnan(out[6]).all() and kept_conf[6] == 0  # below c_min


def test_split_gives_touching_reflectors_their_own_centres():
    blob_id = np.zeros((40, 60), np.uint16)
    blob_id[20:24, 20:24] = 1  # two 16 px patches that touch: one 32 px region
    blob_id[20:24, 24:28] = 1
    area = np.array([32])
    rules = replace(RULES, region_radius_px=10.0)  # the whole region is reflector-sized: one centre for all
    xy = np.array([[20.5, 21.0], [27.0, 22.5], [21.0, 22.0]])  # two distinct peaks, and a third near the first
    conf = np.array([0.9, 0.8, 0.5])
    merged, _, _, _ = r2d.filter_frame(xy, conf, blob_id, area, rules)
    np.testing.assert_allclose(merged[0], [23.5, 21.5])  # off: the region's centre, the others suppressed
    assert np.isnan(merged[1:]).all()
    split, kept, size, _ = r2d.filter_frame(xy, conf, blob_id, area, replace(rules, split_px=4.0))
    np.testing.assert_allclose(split[0], [21.5, 21.5])  # each patch's own centre
    np.testing.assert_allclose(split[1], [25.5, 21.5])
    assert np.isnan(split[2]).all() and kept[2] == 0  # within split_px of a stronger estimate: that one's reflector
    assert size[0] == size[1] == 32
    apart = np.array([[True, False, True], [False, True, True], [True, True, True]])  # 0 and 1 are not neighbours
    kept_one, _, _, _ = r2d.filter_frame(xy, conf, blob_id, area, replace(rules, split_px=4.0), may_split=apart)
    np.testing.assert_allclose(kept_one, merged)  # not neighbours on the body: no split, the weaker suppressed


def test_recovery_gives_dropped_estimates_a_second_chance_and_never_moves_a_kept_one():
    blob_id = np.zeros((40, 80), np.uint16)
    blob_id[20:24, 20:32] = 1  # wrist strap and hand patch touching: one 48 px region, centre (25.5, 21.5)
    blob_id[10:13, 60:63] = 2  # a 9 px region, centre (61, 11)
    area = np.array([48, 9])
    rules = replace(RULES, region_radius_px=10.0, split_px=4.0)
    xy = np.array([[20.5, 21.0],  # 0 wrist: the stronger estimate on region 1
                   [30.0, 22.5],  # 1 hand, not a wrist neighbour under may_split: suppressed on the plain pass
                   [53.0, 11.0],  # 2: 7 px left of region 2, beyond snap_px 6
                   [41.0, 30.0]])  # 3: no region within 9 px
    conf = np.array([0.9, 0.8, 0.7, 0.9])
    apart = np.eye(4, dtype=bool)
    plain, plain_conf, _, recovered = r2d.filter_frame(xy, conf, blob_id, area, rules, may_split=apart)
    np.testing.assert_allclose(plain[0], [25.5, 21.5])  # the whole region's centre
    assert np.isnan(plain[1:]).all() and not recovered.any()

    share = apart.copy()
    share[0, 1] = share[1, 0] = True  # wrist and hand may share a region on the second chance
    out, kept, size, recovered = r2d.filter_frame(xy, conf, blob_id, area, replace(rules, recover_snap_px=9.0),
                                                  may_split=apart, may_recover=share)
    np.testing.assert_array_equal(recovered, [False, True, True, False])
    np.testing.assert_allclose(out[0], plain[0])  # the kept estimate stays where it was
    np.testing.assert_allclose(out[1], [28.5, 21.5])  # the hand's own half of the region (k-means): x 26-31
    np.testing.assert_allclose(out[2], [61.0, 11.0])  # the region 8 px away
    assert np.isnan(out[3]).all() and kept[3] == 0
    np.testing.assert_allclose(kept[:3], conf[:3])
    assert list(size) == [48, 48, 9, 0]

    alone, _, _, recovered = r2d.filter_frame(xy, conf, blob_id, area, replace(rules, recover_snap_px=9.0),
                                              may_split=apart, may_recover=apart)
    assert np.isnan(alone[1]).all() and not recovered[1]  # not neighbours: the wrist's region stays its own
    near = xy.copy()
    near[1] = [22.0, 22.0]  # closer than split_px to the wrist's estimate: the same reflector, not recovered
    out, _, _, recovered = r2d.filter_frame(near, conf, blob_id, area, replace(rules, recover_snap_px=9.0),
                                            may_split=apart, may_recover=share)
    assert np.isnan(out[1]).all() and not recovered[1]


def _heatmaps(points_per_frame, off=None, grid=20, stride=4):
    """Confidence maps with a peak per (frame, reflector) point (cells) and an identity-like crop."""
    n_frames, n_refl = len(points_per_frame), len(points_per_frame[0])
    conf = np.zeros((1, n_frames, n_refl, grid, grid))
    for f, points in enumerate(points_per_frame):
        for r, pts in enumerate(points):
            for (x, y), value in pts:
                conf[0, f, r] = np.maximum(conf[0, f, r], value * targets.confidence_maps(
                    np.array([[x, y]]), np.array([True]), (grid, grid), 0.7)[0])
    field = np.zeros((1, n_frames, n_refl, grid, grid, 2)) if off is None else off
    crop = np.tile(np.array([1.0, 0, 0, 0, 1.0, 0]), (1, n_frames, 1))  # crop pixel == image pixel
    return xr.Dataset({"confidence": (("view", "frame", "reflector", "hy", "hx"), conf.astype(np.float16)),
                       "off": (("view", "frame", "reflector", "hy", "hx", "uv"), field.astype(np.float16)),
                       "crop": (("view", "frame", "affine"), crop)},
                      coords={"view": ["cam"], "frame": np.arange(n_frames), "reflector": ["A", "B"][:n_refl]},
                      attrs={"stride": stride})


def _masks(blob_id, blob_area, n_frames):
    area = np.zeros(8, np.int32)
    area[:len(blob_area)] = blob_area
    return xr.Dataset({"blob_id": (("view", "frame", "y", "x"), np.tile(blob_id, (1, n_frames, 1, 1))),
                       "blob_area": (("view", "frame", "blob"), np.tile(area, (1, n_frames, 1)))},
                      coords={"view": ["cam"], "frame": np.arange(n_frames)})


def test_off_decides_between_equally_confident_candidates():
    """Reflector A moves right from (5, 10) to (9, 10); at frame 1 a decoy peak of the same strength sits
    at (9, 4). The OFF (unit +x along row 10) makes the true one win (Eq. 7-9)."""
    stride, grid = 4, 20
    off = np.zeros((1, 2, 1, grid, grid, 2))
    off[0, 1, 0, 9:12, 4:11, 0] = 1.0
    hm = _heatmaps([[[((5, 10), 0.6)]], [[((9, 10), 0.6), ((9, 4), 0.6)]]], off=off, grid=grid, stride=stride)
    blob_id = np.zeros((80, 80), np.uint16)
    true_xy = targets.from_cells(np.array([9.0, 10.0]), stride)  # image pixels (crop is identity)
    decoy_xy = targets.from_cells(np.array([9.0, 4.0]), stride)
    for label, (x, y) in ((1, true_xy), (2, decoy_xy)):
        blob_id[int(y) - 1:int(y) + 2, int(x) - 1:int(x) + 2] = label
    out = r2d.greedy_reflectors(hm, _masks(blob_id, [9, 9], 2), GREEDY)
    assert float(out["confidence"][0, 1, 0]) > 0.95  # E = 0.6 + 0.4 * ~1
    np.testing.assert_allclose([out["x"][0, 1, 0], out["y"][0, 1, 0]], true_xy, atol=0.6)
    no_off = r2d.greedy_reflectors(_heatmaps([[[((5, 10), 0.6)]], [[((9, 10), 0.6), ((9, 4), 0.6)]]]),
                                   _masks(blob_id, [9, 9], 2), GREEDY)
    assert float(no_off["confidence"][0, 1, 0]) == pytest.approx(0.6, abs=0.01)  # E = E^S without motion
    assert out["region_size"].dtype == np.int32 and int(out["region_size"][0, 1, 0]) == 9


def test_one_estimate_per_reflector_and_image():
    hm = _heatmaps([[[((5, 5), 0.9), ((14, 14), 0.5)], [((5, 14), 0.7)]]])
    blob_id = np.zeros((80, 80), np.uint16)
    for label, cell in ((1, (5, 5)), (2, (14, 14)), (3, (5, 14))):
        x, y = targets.from_cells(np.array(cell, float), 4)
        blob_id[int(y) - 1:int(y) + 2, int(x) - 1:int(x) + 2] = label
    out = r2d.greedy_reflectors(hm, _masks(blob_id, [9, 9, 9], 1), GREEDY)
    assert out.sizes["reflector"] == 2
    np.testing.assert_allclose([out["x"][0, 0, 0], out["y"][0, 0, 0]], targets.from_cells(np.array([5.0, 5.0]), 4),
                               atol=0.6)
    np.testing.assert_allclose(out["confidence"][0, 0].values, [0.9, 0.7], atol=0.01)


def _reference_peak_sets(confidence, threshold, max_n):
    """``peak_sets`` as one loop over the maps (the implementation it replaced)."""
    from scipy import ndimage

    c = np.asarray(confidence, np.float32)
    is_peak = (c == ndimage.maximum_filter(c, size=(1, 3, 3), mode="constant")) & (c >= threshold)
    weights = np.clip(np.pad(c, ((0, 0), (1, 1), (1, 1))), 0, None)
    dy, dx = np.mgrid[-1:2, -1:2]
    out = []
    for r in range(len(c)):
        ys, xs = np.nonzero(is_peak[r])
        order = np.argsort(-c[r, ys, xs])[:max_n]
        ys, xs = ys[order], xs[order]
        w = weights[r, ys[:, None, None] + 1 + dy, xs[:, None, None] + 1 + dx]
        total = w.sum(axis=(1, 2))
        cells = np.stack([xs + (w * dx).sum(axis=(1, 2)) / total, ys + (w * dy).sum(axis=(1, 2)) / total], axis=1)
        out.append((cells.astype(np.float64).reshape(-1, 2), c[r, ys, xs].astype(np.float64)))
    return out


def _reference_suppress_close(xy, confidence, min_distance):
    keep = np.isfinite(xy[:, 0])
    for i in np.argsort(-confidence):
        if not keep[i]:
            continue
        close = np.linalg.norm(xy - xy[i], axis=1) < min_distance
        close[i] = False
        keep &= ~(close & (confidence <= confidence[i]))
    return keep


@pytest.mark.parametrize("max_n", [1, 3, 40])
def test_peak_sets_equal_the_per_map_loop_bit_for_bit(max_n):
    rng = np.random.default_rng(4)
    maps = rng.uniform(-0.1, 1.0, (12, 32, 32)).astype(np.float16)  # float16, as stored: equal peaks happen
    maps[3] = 0.0  # a map without peaks
    maps[5, ::4, ::4] = 0.5  # a map of tied peaks
    for (cells, values), (ref_cells, ref_values) in zip(r2d.peak_sets(maps, 0.1, max_n),
                                                        _reference_peak_sets(maps, 0.1, max_n), strict=True):
        np.testing.assert_array_equal(cells, ref_cells)
        np.testing.assert_array_equal(values, ref_values)


def test_line_integral_sets_pair_every_start_with_every_end_row_major():
    rng = np.random.default_rng(5)
    fields = rng.normal(size=(4, 16, 20, 2))
    starts = [rng.uniform(0, 16, (m, 2)) for m in (2, 0, 3, 1)]
    ends = [rng.uniform(0, 16, (n, 2)) for n in (3, 2, 0, 2)]
    for field, a, b, table in zip(fields, starts, ends, r2d.line_integral_sets(fields, starts, ends, 10)):
        assert table.shape == (len(a), len(b))
        for i in range(len(a)):
            for j in range(len(b)):
                assert table[i, j] == r2d.line_integral(field, a[i], b[j], 10)


def test_suppress_close_equals_the_pairwise_loop():
    rng = np.random.default_rng(6)
    for _ in range(50):
        xy = rng.uniform(0, 12, (20, 2))
        xy[rng.uniform(size=20) < 0.2] = np.nan
        confidence = np.round(rng.uniform(0, 1, 20), 1)  # ties
        np.testing.assert_array_equal(r2d.suppress_close(xy, confidence, 3.0),
                                      _reference_suppress_close(xy, confidence, 3.0))

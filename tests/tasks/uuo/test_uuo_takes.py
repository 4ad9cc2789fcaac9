"""Unlabelled marker takes on the mesh body: layouts on a part, paths 9.5 mm off the skin, capture faults (by default
an optical system's: occlusion by the body, breaks and their fragments, ghosts near the body)."""

from __future__ import annotations

import numpy as np
import pytest

from mocapflow.tasks.uuo import takes as uuo
from mocapflow.tasks.studio.mesh_render import MeshScene, surface_points
from mocapflow.tasks.deepmocap.film.synth import build_rig
from mocapflow.tasks.studio.spec import SequenceSpec


@pytest.fixture(scope="module")
def take():
    rig = build_rig(SequenceSpec("jumping_jack", frames=40, seed=12, body="mesh", views=1))
    markers = uuo.layout(rig.body, np.random.default_rng(5), 40)
    return rig, markers, uuo.marker_paths(rig.body, markers, rig.take.posed.vertices[:40])


def test_markers_ride_9_5_mm_off_the_skin_of_their_part(take):
    rig, markers, paths = take
    assert paths.shape == (40, 40, 3)
    for f in (0, 17, 39):
        skin, normal = surface_points(rig.take.posed.vertices[f], rig.body.faces, markers.faces, markers.bary)
        np.testing.assert_allclose(np.linalg.norm(paths[f] - skin, axis=1), 0.0095, atol=1e-9)
        assert (np.einsum("mi,mi->m", paths[f] - skin, normal) > 0).all()  # outside the body
    arm = uuo.layout(rig.body, np.random.default_rng(6), 20, "right_arm")
    assert rig.body.part_faces("right_arm")[arm.faces].all()
    # jumping jacks: the whole body bounces, the markers on the swinging limbs travel twice as far
    travel = np.linalg.norm(np.diff(paths, axis=0), axis=2).sum(axis=0)
    assert travel.min() > 0.2 and travel.max() > 1.8 * travel.min()


def test_a_clean_capture_is_the_truth_with_jitter_in_shuffled_ids(take):
    _, _, paths = take
    clean = uuo.capture(paths, uuo.MarkerFaults.clean(), np.random.default_rng(1))
    assert clean.positions.shape == paths.shape and sorted(clean.source) == list(range(40))
    assert not np.array_equal(clean.source, np.arange(40))  # the order says nothing
    error_mm = 1000 * np.linalg.norm(clean.positions - paths[:, clean.source], axis=2)
    assert 0.5 * np.sqrt(3) * 0.8 < np.median(error_mm) < 1.0 * np.sqrt(3) * 1.2  # sigma 0.5-1 mm per axis


def test_dropout_hides_runs_and_fragments_the_ids(take):
    _, _, paths = take
    faults = uuo.MarkerFaults.clean(dropout=0.01, gap_frames=10, ghosts_per_s=2.25)  # 40 frames at 30/s: 3 ghosts
    rec = uuo.capture(paths, faults, np.random.default_rng(2), fps=30.0)
    ghosts = rec.source == -1
    assert ghosts.sum() == 3
    real = rec.positions[:, ~ghosts]
    hidden = np.isnan(real[..., 0]).all(axis=1)
    assert hidden.sum() == 0  # every id has at least one sample
    # each id is one unbroken run of samples of its true marker (a gap starts a new id)
    for k in np.flatnonzero(~ghosts):
        present = ~np.isnan(rec.positions[:, k, 0])
        runs = np.diff(np.concatenate([[0], present.astype(int), [0]]))
        assert (runs == 1).sum() == 1
        err = np.linalg.norm(rec.positions[present, k] - paths[present, rec.source[k]], axis=1)
        assert err.max() < 0.006
    fragmented = np.bincount(rec.source[~ghosts], minlength=40)
    assert fragmented.min() >= 1 and fragmented.max() > 1 and len(rec.source) > 40
    # a ghost lives a few frames near the body, follows no marker
    for k in np.flatnonzero(ghosts):
        present = ~np.isnan(rec.positions[:, k, 0])
        assert 3 <= present.sum() <= 15
    # without fragmentation, gaps stay inside one id per marker
    whole = uuo.capture(paths, uuo.MarkerFaults.clean(dropout=0.01, fragment=False), np.random.default_rng(2))
    assert sorted(whole.source) == list(range(40)) and np.isnan(whole.positions).any()


def test_the_hidden_share_follows_the_dropout_rate(take):
    _, _, paths = take
    long = np.repeat(paths, 10, axis=0)  # 400 frames
    rec = uuo.capture(long, uuo.MarkerFaults.clean(dropout=0.01, fragment=False), np.random.default_rng(3))
    hidden = np.isnan(rec.positions[..., 0]).mean()
    # a run of 10 starts on about 1 % of the seen frames: hidden share p g / (1 + p g) = 9 %
    assert 0.06 < hidden < 0.12


def test_bad_faults_are_refused():
    with pytest.raises(uuo.MarkerTakeError, match="dropout is a per-frame probability"):
        uuo.MarkerFaults(dropout=1.5)
    with pytest.raises(uuo.MarkerTakeError, match="jitter_mm must be a range"):
        uuo.MarkerFaults(jitter_mm=(2.0, 1.0))
    for rates in ({"ghosts_per_s": -1.0}, {"break_per_s": float("nan")}):
        with pytest.raises(uuo.MarkerTakeError, match="are rates per second, >= 0"):
            uuo.MarkerFaults(**rates)
    with pytest.raises(uuo.MarkerTakeError, match="ghost_reach_m must be >= 0.05"):
        uuo.MarkerFaults(ghost_reach_m=0.01)
    with pytest.raises(uuo.MarkerTakeError, match="capture needs the take's frame rate"):
        uuo.capture(np.zeros((5, 2, 3)), uuo.MarkerFaults(occlusion=False), np.random.default_rng(0))


def _embree_cameras_seeing(vertices, faces, points, cameras, tolerance_m=2e-3):
    """The count as embree casts it: a scene per frame, a ray per camera and marker."""
    count = np.zeros(points.shape[:2], np.int64)
    for f in range(len(points)):
        scene = MeshScene(vertices[f], faces)
        for cam in cameras:
            ray = points[f] - cam
            dist = np.linalg.norm(ray, axis=1)
            _, _, t = scene.cast(np.broadcast_to(cam, ray.shape), ray / dist[:, None])
            count[f] += t >= dist - tolerance_m
    return count


def _runs(present):
    """Lengths of the runs of True in a 1-d mask."""
    edges = np.diff(np.concatenate([[0], present.astype(int), [0]]))
    return np.flatnonzero(edges == -1) - np.flatnonzero(edges == 1)


def test_occlusion_loses_the_markers_fewer_than_two_cameras_see(take):
    rig, _, paths = take
    vertices = rig.take.posed.vertices[:40]
    cameras = uuo.optical_cameras()
    assert cameras.shape == (8, 3) and np.allclose(np.linalg.norm(cameras[:, :2], axis=1), 3.5)
    seen_by = uuo.cameras_seeing(vertices, rig.body.faces, paths, cameras)
    assert seen_by.shape == (40, 40) and seen_by.max() <= 8
    assert (seen_by >= 2).mean() > 0.8 and (seen_by < 8).any()  # most markers seen; the body hides some from some
    # the same counts as embree's ray casts, a scene per frame
    some = np.array([0, 13, 26, 39])
    np.testing.assert_array_equal(seen_by[some], _embree_cameras_seeing(vertices[some], rig.body.faces, paths[some],
                                                                        cameras))
    # a camera in the body's middle sees nothing through the skin
    inside = uuo.cameras_seeing(vertices[:1], rig.body.faces, paths[:1], vertices[0].mean(0, keepdims=True))
    assert inside.sum() == 0
    rec = uuo.capture(paths, uuo.MarkerFaults.clean(occlusion=True, fragment=False), np.random.default_rng(3), seen_by)
    kept = np.isfinite(rec.positions[..., 0])  # (frame, id), ids in shuffled order
    np.testing.assert_array_equal(kept, seen_by[:, rec.source] >= 2)  # lost exactly where fewer than two see it
    with pytest.raises(uuo.MarkerTakeError, match="occlusion needs how many cameras"):
        uuo.capture(paths, uuo.MarkerFaults(occlusion=True), np.random.default_rng(3), fps=30.0)


def test_by_default_a_marker_on_the_back_is_lost_to_the_cameras_in_front(take):
    """The defaults are an optical system's; with the cameras of the ring's front half only (the body faces +Y), the
    markers on the back are seen by fewer than two and lost on every frame, those on the chest kept."""
    faults = uuo.MarkerFaults()
    assert faults.occlusion and faults.min_cameras == 2 and faults.fragment
    assert (faults.ghosts_per_s, faults.break_per_s) == (2.0, 0.1)
    rig, _, _ = take
    vertices = rig.take.posed.vertices[:40]
    torso = uuo.layout(rig.body, np.random.default_rng(7), 60, "torso")
    _, normal = surface_points(vertices[0], rig.body.faces, torso.faces, torso.bary)
    back, chest = normal[:, 1] < -0.8, normal[:, 1] > 0.8
    assert back.sum() >= 10 and chest.sum() >= 10
    ring = uuo.optical_cameras()
    front = ring[ring[:, 1] > 0.1]
    assert len(front) == 3
    paths = uuo.marker_paths(rig.body, torso, vertices)
    seen_by = uuo.cameras_seeing(vertices, rig.body.faces, paths, front)
    assert seen_by[:, back].max() <= 1 and (seen_by[:, chest] == 3).all()
    no_extras = dict(break_per_s=0.0, ghosts_per_s=0.0)
    rec = uuo.record(rig.body, torso, vertices, uuo.MarkerFaults(**no_extras), np.random.default_rng(1), 30.0, front)
    assert not np.isin(rec.source, np.flatnonzero(back)).any()  # no trajectory of a back marker at all
    chest_ids = np.isin(rec.source, np.flatnonzero(chest))
    assert chest_ids.sum() == chest.sum() and np.isfinite(rec.positions[:, chest_ids]).all()  # one whole id each
    # the whole ring sees the back from behind: by default a back marker is kept wherever two cameras see it
    rec = uuo.record(rig.body, torso, vertices, uuo.MarkerFaults(**no_extras), np.random.default_rng(1), 30.0)
    assert np.isin(np.flatnonzero(back), rec.source).all()
    # the all-visible option loses none of them, behind the body or not
    rec = uuo.record(rig.body, torso, vertices, uuo.MarkerFaults(occlusion=False, **no_extras),
                     np.random.default_rng(1), 30.0, front)
    assert sorted(rec.source) == list(range(60)) and np.isfinite(rec.positions).all()


def test_occlusion_flicker_leaves_fragments_of_the_runs_two_cameras_see(take):
    """Every trajectory of a marker is one run of frames at least two cameras see it in; where the count hovers at
    two the runs, and so the fragments, are short."""
    rig, _, paths = take
    seen_by = uuo.cameras_seeing(rig.take.posed.vertices[:40], rig.body.faces, paths, uuo.optical_cameras())
    rec = uuo.capture(paths, uuo.MarkerFaults.clean(occlusion=True), np.random.default_rng(5), seen_by)
    present = np.isfinite(rec.positions[..., 0])
    lengths = present.sum(axis=0)
    for m in range(40):
        ids = np.flatnonzero(rec.source == m)
        assert sorted(lengths[ids]) == sorted(_runs(seen_by[:, m] >= 2))
        for k in ids:
            assert len(_runs(present[:, k])) == 1 and (seen_by[present[:, k], m] >= 2).all()
    assert len(rec.source) > 40 and lengths.min() <= 3  # some marker flickers: fragments of a few frames


def test_breaks_cut_trajectories_at_the_stated_rate_after_one_lost_frame(take):
    _, _, paths = take
    long = np.repeat(paths, 75, axis=0)  # 3000 frames, 100 s at 30 frames/s
    rec = uuo.capture(long, uuo.MarkerFaults.clean(break_per_s=0.5), np.random.default_rng(4), fps=30.0)
    assert (rec.source >= 0).all()
    present = np.isfinite(rec.positions[..., 0])
    breaks = np.bincount(rec.source, minlength=40) - 1  # each marker: its fragments less one
    # 0.5 a second for 100 s: 50 a marker, 2000 in all (binomial sd 45)
    assert 1850 < breaks.sum() < 2150 and breaks.min() > 25
    lengths = present.sum(axis=0)
    assert 54 < lengths.mean() < 62  # about 58 frames: 3000 in 51 fragments, less the lost frames
    gaps = []
    for m in range(40):
        ids = np.flatnonzero(rec.source == m)
        spans = sorted((np.flatnonzero(present[:, k])[0], np.flatnonzero(present[:, k])[-1]) for k in ids)
        gaps += [b[0] - a[1] - 1 for a, b in zip(spans, spans[1:])]
    gaps = np.array(gaps)
    assert gaps.min() >= 1 and (gaps == 1).mean() > 0.98  # one frame lost, then a new id (two breaks in a row: 2)
    assert present.sum() == 3000 * 40 - gaps.sum()  # nothing else lost
    # the default rate on the 40-frame take: a few breaks among 40 markers (0.1/s x 1.33 s x 40 = 5.3 expected)
    rec = uuo.capture(paths, uuo.MarkerFaults.clean(break_per_s=0.1), np.random.default_rng(4), fps=30.0)
    assert 1 <= len(rec.source) - 40 <= 12


def test_ghosts_come_at_the_stated_rate_near_the_body_and_short_lived(take):
    _, _, paths = take
    faults = uuo.MarkerFaults.clean(ghosts_per_s=2.0)
    for repeat, expected in ((1, 40 / 15), (3, 8.0), (10, 80 / 3), (75, 200.0)):
        long = np.repeat(paths, repeat, axis=0)
        counts = [int((uuo.capture(long, faults, np.random.default_rng(seed), fps=30.0).source == -1).sum())
                  for seed in range(3)]
        assert all(np.floor(expected) <= c <= np.ceil(expected) for c in counts), (expected, counts)
    assert uuo.ghost_count(1.25 * 0.8, np.random.default_rng(0)) == 1  # an exact count is exact
    rec = uuo.capture(long, faults, np.random.default_rng(6), fps=30.0)  # 3000 frames, 200 ghosts
    ghosts = np.flatnonzero(rec.source == -1)
    assert len(ghosts) == 200
    present = np.isfinite(rec.positions[:, ghosts, 0])
    lives = present.sum(axis=0)
    assert lives.min() >= 3 and lives.max() <= 15 and 7 < lives.mean() < 11  # 3-15 frames, 9 on average
    starts = present.argmax(axis=0)
    assert 0.35 < (starts < 1500).mean() < 0.65  # spread over the take
    near = np.array([np.linalg.norm(long[alive] - rec.positions[alive, g][:, None], axis=2).min(axis=1).max()
                     for g, alive in zip(ghosts, present.T)])  # each ghost's farthest from the body's markers
    assert near.max() < 0.35 and np.median(near) < 0.25  # within 30 cm of a true marker (and a few mm of drift)
    # the all-visible take has no ghost
    assert (uuo.capture(long, uuo.MarkerFaults.clean(), np.random.default_rng(6)).source >= 0).all()


def test_a_take_is_the_same_for_the_same_seed_and_another_for_another(take):
    rig, markers, _ = take
    vertices = rig.take.posed.vertices[:40]
    first, again, other = (uuo.record(rig.body, markers, vertices, uuo.MarkerFaults(), np.random.default_rng(seed),
                                      30.0) for seed in (11, 11, 12))
    np.testing.assert_array_equal(first.positions, again.positions)
    np.testing.assert_array_equal(first.source, again.source)
    assert first.positions.shape != other.positions.shape or not np.array_equal(first.source, other.source)
    assert (first.source == -1).sum() in (2, 3)  # 2 ghosts a second for 1.33 s
    assert np.isnan(first.positions).any() and len(first.source) > 43  # occlusion and breaks fragment the ids

"""Unlabelled marker takes on the mesh body: layouts on a part, paths 9.5 mm off the skin, capture faults."""

from __future__ import annotations

import numpy as np
import pytest

from mocapflow.tasks.studio import uuo_takes as uuo
from mocapflow.tasks.studio.mesh_render import surface_points
from mocapflow.tasks.studio.synth import SequenceSpec, build_rig


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
    clean = uuo.capture(paths, uuo.MarkerFaults(), np.random.default_rng(1))
    assert clean.positions.shape == paths.shape and sorted(clean.source) == list(range(40))
    assert not np.array_equal(clean.source, np.arange(40))  # the order says nothing
    error_mm = 1000 * np.linalg.norm(clean.positions - paths[:, clean.source], axis=2)
    assert 0.5 * np.sqrt(3) * 0.8 < np.median(error_mm) < 1.0 * np.sqrt(3) * 1.2  # sigma 0.5-1 mm per axis


def test_dropout_hides_runs_and_fragments_the_ids(take):
    _, _, paths = take
    faults = uuo.MarkerFaults(dropout=0.01, gap_frames=10, ghosts=3)
    rec = uuo.capture(paths, faults, np.random.default_rng(2))
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
    whole = uuo.capture(paths, uuo.MarkerFaults(dropout=0.01, fragment=False), np.random.default_rng(2))
    assert sorted(whole.source) == list(range(40)) and np.isnan(whole.positions).any()


def test_the_hidden_share_follows_the_dropout_rate(take):
    _, _, paths = take
    long = np.repeat(paths, 10, axis=0)  # 400 frames
    rec = uuo.capture(long, uuo.MarkerFaults(dropout=0.01, fragment=False), np.random.default_rng(3))
    hidden = np.isnan(rec.positions[..., 0]).mean()
    # a run of 10 starts on about 1 % of the seen frames: hidden share p g / (1 + p g) = 9 %
    assert 0.06 < hidden < 0.12


def test_bad_faults_are_refused():
    with pytest.raises(uuo.MarkerTakeError, match="dropout is a per-frame probability"):
        uuo.MarkerFaults(dropout=1.5)
    with pytest.raises(uuo.MarkerTakeError, match="jitter_mm must be a range"):
        uuo.MarkerFaults(jitter_mm=(2.0, 1.0))


def test_occlusion_loses_the_markers_fewer_than_two_cameras_see(take):
    rig, _, paths = take
    vertices = rig.take.posed.vertices[:40]
    cameras = uuo.optical_cameras()
    assert cameras.shape == (8, 3) and np.allclose(np.linalg.norm(cameras[:, :2], axis=1), 3.5)
    seen_by = uuo.cameras_seeing(vertices, rig.body.faces, paths, cameras)
    assert seen_by.shape == (40, 40) and seen_by.max() <= 8
    assert (seen_by >= 2).mean() > 0.8 and (seen_by < 8).any()  # most markers seen; the body hides some from some
    # a camera in the body's middle sees nothing through the skin
    inside = uuo.cameras_seeing(vertices[:1], rig.body.faces, paths[:1], vertices[0].mean(0, keepdims=True))
    assert inside.sum() == 0
    rec = uuo.capture(paths, uuo.MarkerFaults(occlusion=True, fragment=False), np.random.default_rng(3), seen_by)
    kept = np.isfinite(rec.positions[..., 0])  # (frame, id), ids in shuffled order
    np.testing.assert_array_equal(kept, seen_by[:, rec.source] >= 2)  # lost exactly where fewer than two see it
    with pytest.raises(uuo.MarkerTakeError, match="occlusion needs how many cameras"):
        uuo.capture(paths, uuo.MarkerFaults(occlusion=True), np.random.default_rng(3))

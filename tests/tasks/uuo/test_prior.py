"""UUO's monocular prior, simulated from the studio's truth: errors of the chosen size, the truth without them."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from mocapflow.tasks.uuo import takes as uuo
from mocapflow.tasks.deepmocap.film.synth import build_rig
from mocapflow.tasks.studio.spec import SequenceSpec
from mocapflow.tasks.shared.kinematics import local_rotations
from mocapflow.tasks.shared.mesh_body import Phenotype, mesh_body
from mocapflow.tasks.uuo import prior


@pytest.fixture(scope="module")
def take():
    rig = build_rig(SequenceSpec("side_reaches", frames=40, seed=31, body="mesh", views=1))
    layout = uuo.layout(rig.body, np.random.default_rng(1), 30)
    rec = uuo.capture(uuo.marker_paths(rig.body, layout, rig.take.posed.vertices[:40]), uuo.MarkerFaults.clean(),
                      np.random.default_rng(2))
    return uuo.marker_dataset(rig.body, layout, rec, rig.take, 30.0, 0, 40)


def test_a_prior_without_errors_is_the_truth(take):
    exact = prior.SimulatedPriorConfig(form="mild", rotation_deg=0.0, yaw_deg=0.0, scale_range=(1.0, 1.0),
                                       translation_m=0.0,
                                       lost=0.0, phenotype_noise=0.0, drift_m=0.0)
    out = prior.simulated_prior(take, exact)
    np.testing.assert_allclose(out.joints.values, take.gt_joints.values, atol=1e-5)
    assert out.valid.values.all() and out.attrs["registered_mpjpe_mm"] < 0.01


def test_the_default_prior_errs_like_a_monocular_estimate(take):
    out = prior.simulated_prior(take, prior.SimulatedPriorConfig(seed=4))
    assert out.attrs["form"] == "realistic"
    seeds = [out.attrs] + [prior.simulated_prior(take, prior.SimulatedPriorConfig(seed=s)).attrs for s in (5, 6)]
    aligned = [a["aligned_mpjpe_mm"] for a in seeds]
    # after part matching's own alignment (HMR2.0+RR: 132-150 mm): measured 177, 150 and 201 mm for seeds 4-6, a
    # median of 177; 150 keeps out the mild form's error (121 mm on seed 4), 200 a prior much worse than published
    assert 150 < np.median(aligned) < 200, aligned
    pa = [a["pa_mpjpe_mm"] for a in seeds]  # articulated: a part of it; measured 153, 140, 125 mm (median 140)
    assert 110 < np.median(pa) < np.median(aligned), (pa, aligned)
    raw = np.linalg.norm(out.joints.values - take.gt_joints.values, axis=2).mean()
    assert raw > 0.3  # unregistered: off by the unknown position, size and yaw
    # one yaw for the take: the root turns by the same angle about the vertical in every frame
    truth = Rotation.from_quat(take.gt_bone_rotations.values[:, 0])
    est = Rotation.from_quat(out.bone_rotation.values[:, 0])
    yaw = np.degrees([np.arctan2(m[1, 0], m[0, 0]) for m in (est * truth.inv()).as_matrix()])
    assert np.ptp(np.unwrap(np.radians(yaw))) < np.radians(40)
    again = prior.simulated_prior(take, prior.SimulatedPriorConfig(seed=4))
    assert np.array_equal(again.joints.values, out.joints.values)


def test_lost_frames_hold_a_kept_one_and_are_marked(take):
    out = prior.simulated_prior(take, prior.SimulatedPriorConfig(lost=0.3, seed=5))
    lost = ~out.valid.values
    assert 0 < lost.sum() < 40
    kept = out.joints.values[~lost]
    for f in np.flatnonzero(lost):
        assert any(np.array_equal(out.joints.values[f], k) for k in kept)


def test_recorded_markers_without_truth_are_refused_with_the_fix(take):
    with pytest.raises(prior.PriorError, match="prior: file .* or prior: none"):
        prior.simulated_prior(take.drop_vars(["gt_bone_rotations"]), prior.SimulatedPriorConfig())
    with pytest.raises(prior.PriorError, match="rotation_deg"):
        prior.SimulatedPriorConfig(rotation_deg=-1)


def test_aligned_mpjpe_removes_one_rotation_and_a_translation_per_frame_but_not_a_pose_error():
    rng = np.random.default_rng(0)
    truth = rng.normal(size=(5, 20, 3))
    turn = Rotation.from_euler("zx", [70, 20], degrees=True).as_matrix()
    moved = truth @ turn.T + rng.normal(size=(5, 1, 3))  # one rotation, a translation per frame
    assert prior.aligned_mpjpe(moved, truth) < 1e-9
    bent = truth.copy()
    bent[:, 0] += [0.2, 0.0, 0.0]  # one joint 20 cm off in every frame: 19 of 20 joints right
    assert 0.005 < prior.aligned_mpjpe(bent, truth) < 0.02
    assert prior.aligned_mpjpe(bent, truth) <= prior.registered_mpjpe(bent, truth) + 0.02


def test_the_realistic_prior_errs_in_correlated_ways_and_every_bone_is_off(take):
    mild = prior.simulated_prior(take, prior.SimulatedPriorConfig(form="mild", seed=4))
    real = prior.simulated_prior(take, prior.SimulatedPriorConfig(seed=4))
    assert real.attrs["aligned_mpjpe_mm"] > mild.attrs["aligned_mpjpe_mm"] + 20
    body = mesh_body(Phenotype(**take.attrs["phenotype"]))

    def local(quats):
        world = Rotation.from_quat(quats.reshape(-1, 4)).as_matrix().reshape(quats.shape[:2] + (3, 3))
        return Rotation.from_matrix(local_rotations(world, body.bone_parents).reshape(-1, 3, 3))

    truth = local(take.gt_bone_rotations.values)
    own = {label: np.degrees((local(ds.bone_rotation.values) * truth.inv()).magnitude()).reshape(40, -1).max(0)
           for label, ds in (("mild", mild), ("realistic", real))}
    others = np.array([n not in prior.PRIOR_BONES for n in body.bone_names])
    assert (own["mild"][others] < 1e-6).all()  # mild: the bones outside PRIOR_BONES keep their true rotations
    assert (own["realistic"] > 0.5).all()  # realistic: every bone degraded
    # errors last: the joint error of adjacent frames is strongly correlated (not independent per frame)
    err = (real.joints.values - take.gt_joints.values)
    err = err - err.mean(axis=1, keepdims=True)
    a, b = err[:-1].ravel(), err[1:].ravel()
    assert np.corrcoef(a, b)[0, 1] > 0.8
    with pytest.raises(prior.PriorError, match="form 'heavy' is unknown"):
        prior.SimulatedPriorConfig(form="heavy")


def test_one_seed_gives_each_take_errors_of_its_own_and_the_same_take_the_same(take):
    """The catalog's one prior seed is mixed with each take's own key: takes of a benchmark are not degraded by
    one shared draw (the same yaw offset, the same flips at the same frames), and a take's prior is repeatable."""
    config = prior.SimulatedPriorConfig(seed=4)
    shift = np.array([1.0, 0.0, 0.0])
    moved = take.assign(gt_root=take["gt_root"] + shift, gt_joints=take["gt_joints"] + shift.astype(np.float32))
    assert prior.take_key(take.attrs["phenotype"], take["gt_root"].values) != \
        prior.take_key(moved.attrs["phenotype"], moved["gt_root"].values)
    first, again, other = (prior.simulated_prior(t, config) for t in (take, take, moved))
    np.testing.assert_array_equal(first["joints"].values, again["joints"].values)  # the same take, the same errors
    # with the same draws the moved take's prior would be the first one moved by the shift (placement commutes)
    apart = np.linalg.norm(other["joints"].values - shift - first["joints"].values, axis=-1).mean()
    assert apart > 0.05, apart  # its own errors: on average more than 5 cm from the first take's

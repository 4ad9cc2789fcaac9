"""UUO's `file` prior: a monocular estimate's joints fitted by Anny's rig, lost frames held and marked."""

from __future__ import annotations

import numpy as np
import pytest

from mocapflow.tasks.uuo import takes as uuo
from mocapflow.tasks.deepmocap.film.synth import build_rig
from mocapflow.tasks.studio.spec import SequenceSpec
from mocapflow.tasks.uuo import prior


@pytest.fixture(scope="module")
def take():
    rig = build_rig(SequenceSpec("side_reaches", frames=30, seed=33, body="mesh", views=1))
    layout = uuo.layout(rig.body, np.random.default_rng(1), 20)
    rec = uuo.capture(uuo.marker_paths(rig.body, layout, rig.take.posed.vertices[:30]), uuo.MarkerFaults.clean(),
                      np.random.default_rng(2))
    return uuo.marker_dataset(rig.body, layout, rec, rig.take, 30.0, 0, 30)


def _with_prior(take, joints):
    return take.assign(prior_joints=(("frame", "joint", "xyz"), joints.astype(np.float32)))


def test_a_prior_of_known_joints_comes_back_as_a_body_with_those_joints(take):
    joints = take.gt_joints.values.astype(np.float64).copy()
    joints[7] = np.nan  # a lost frame
    out = prior.file_prior(_with_prior(take, joints), prior.FilePriorConfig())
    assert out.attrs["source"] == "file" and out.joints.shape == (30, 20, 3) and out.bone_rotation.shape[1] == 104
    assert list(out.valid.values) == [f != 7 for f in range(30)]
    error = np.linalg.norm(out.joints.values - take.gt_joints.values, axis=-1)  # (frame, joint) m
    kept = np.delete(error, 7, axis=0)
    assert kept.mean() < 0.015 and np.percentile(kept, 95) < 0.04, (kept.mean(), np.percentile(kept, 95))
    assert out.attrs["fit_error_mm"] == pytest.approx(1000 * kept.mean(), rel=1e-4)
    np.testing.assert_array_equal(out.joints.values[7], out.joints.values[6])  # held by the nearest kept frame
    # the fitted body's size follows the joints: the truth's phenotype height within a few per cent of its range
    assert abs(out.attrs["phenotype"]["height"] - take.attrs["phenotype"]["height"]) < 0.1


def test_a_take_without_a_prior_file_or_with_every_frame_lost_is_refused(take):
    with pytest.raises(prior.PriorError, match="'prior' folder"):
        prior.file_prior(take, prior.FilePriorConfig())
    with pytest.raises(prior.PriorError, match="every frame of the prior is lost"):
        prior.file_prior(_with_prior(take, np.full((30, 20, 3), np.nan)), prior.FilePriorConfig())
    with pytest.raises(prior.PriorError, match="iterations >= 1"):
        prior.FilePriorConfig(iterations=0)


def test_the_reference_prior_degrades_a_solved_body_as_the_simulated_one_degrades_the_truth(take):
    import xarray as xr

    reference = xr.Dataset({"bone_rotation": take.gt_bone_rotations, "root": take.gt_root,
                            "joints": take.gt_joints}, attrs={"phenotype": take.attrs["phenotype"]})
    config = prior.SimulatedPriorConfig(seed=3)
    a, b = prior.reference_prior(take, reference, config), prior.simulated_prior(take, config)
    np.testing.assert_allclose(a.joints.values, b.joints.values, atol=1e-6)
    assert a.attrs["source"] == "reference" and a.attrs["registered_mpjpe_mm"] == b.attrs["registered_mpjpe_mm"]

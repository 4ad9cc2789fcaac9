"""UUO's hypotheses: the mirrored body, the hinges' flexion, travel, and which placements are worth a solve."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from mocapflow.tasks.shared import mesh_body as mb
from mocapflow.tasks.shared.body import JOINT_NAMES
from mocapflow.tasks.shared.kinematics import world_rotations
from mocapflow.tasks.shared.solver_body import BodyFit, SolverBody, posed_heads
from mocapflow.tasks.deepmocap.film.synth import build_rig
from mocapflow.tasks.studio.spec import SequenceSpec
from mocapflow.tasks.uuo import hypotheses as hyp, metrics


@pytest.fixture(scope="module")
def body():
    b = mb.mesh_body(mb.Phenotype())
    return b, SolverBody(b)


def _random_fit(b, frames=3, seed=0):
    rng = np.random.default_rng(seed)
    local = Rotation.from_rotvec(rng.normal(0, 0.4, (frames * len(b.bone_names), 3))).as_matrix()
    return BodyFit(local.reshape(frames, -1, 3, 3), rng.normal(0, 1, (frames, 3)),
                   np.array([getattr(mb.Phenotype(), k) for k in mb.PHENOTYPE_NAMES]))


def test_the_mirrored_body_is_the_reflection_through_its_own_sagittal_plane(body):
    b, solver = body
    bones = hyp.mirror_bones(b.bone_names)
    names = list(b.bone_names)
    assert names[bones[names.index("lowerleg01.L")]] == "lowerleg01.R" and bones[0] == 0
    fit = _random_fit(b)
    twice = hyp.mirrored(hyp.mirrored(fit, bones), bones)
    np.testing.assert_allclose(twice.local, fit.local, atol=1e-12)
    heads, mirrored = posed_heads(solver, fit), posed_heads(solver, hyp.mirrored(fit, bones))
    root = fit.local[:, 0]
    plane = root @ hyp.MIRROR @ np.swapaxes(root, -1, -2)  # the posed body's own reflection
    expected = heads[:, :1] + np.einsum("fij,fbj->fbi", plane, heads - heads[:, :1])
    assert np.abs(mirrored[:, bones] - expected).max() < 0.003  # Anny's rest is symmetric to 2 mm
    assert np.abs(mirrored - heads).max() > 0.1  # a random pose is not its own mirror image
    assert not hyp.is_symmetric(solver, fit, bones, 0.01)
    rest = BodyFit(np.broadcast_to(np.eye(3), fit.local.shape).copy(), fit.root, fit.phenotype)
    assert hyp.is_symmetric(solver, rest, bones, 0.01)  # the rest pose of markers only: no mirror to try


def test_true_poses_bend_their_hinges_their_way_and_a_knee_bent_backward_is_counted():
    rig = build_rig(SequenceSpec("classic_squat", frames=30, seed=41, body="mesh", views=1))
    flexion = hyp.hinge_flexion_deg(rig.body, rig.take.rotations, rig.take.posed.heads)
    assert flexion.shape[1] == 4
    assert flexion[:, :2].max() > 80 and flexion.min() > -2  # a squat bends the knees forward, none backward
    assert hyp.hyperextension_deg(flexion, 10.0) == 0.0
    b = rig.body
    solver = SolverBody(b)
    fit = BodyFit(np.broadcast_to(np.eye(3), (1, len(b.bone_names), 3, 3)).copy(), b.rest_heads[:1].copy(),
                  np.array([getattr(b.phenotype, k) for k in mb.PHENOTYPE_NAMES]))
    knee = b.bone("lowerleg01.L")

    def flexion_of(bend_deg):  # the left knee turned about the rest hinge axis (-x at the knee)
        local = fit.local.copy()
        local[0, knee] = Rotation.from_rotvec(np.radians(bend_deg) * np.array([1.0, 0.0, 0.0])).as_matrix()
        bent = BodyFit(local, fit.root, fit.phenotype)
        return hyp.hinge_flexion_deg(b, world_rotations(bent.local, b.bone_parents), posed_heads(solver, bent))[0, 0]

    rest = flexion_of(0.0)
    assert 0.0 < rest < 12.0  # Anny's rest knee is a little bent
    assert flexion_of(-40.0) - rest == pytest.approx(40.0, abs=1.0)
    assert flexion_of(40.0) - rest == pytest.approx(-40.0, abs=1.0)
    assert hyp.hyperextension_deg(np.array([[-40.0, 0.0, -5.0, 0.0]]), 10.0) == pytest.approx(30.0)


def test_a_body_walking_backward_is_told_from_one_walking_forward_or_standing():
    frames = 60
    joints = np.zeros((frames, len(JOINT_NAMES), 3))
    joints[:, JOINT_NAMES.index("LeftHip")] = [-0.1, 0.0, 0.9]  # facing +y: left is -x
    joints[:, JOINT_NAMES.index("RightHip")] = [0.1, 0.0, 0.9]
    assert np.degrees(metrics.facing(joints, JOINT_NAMES)[0]) == pytest.approx(90.0)
    walk = joints.copy()
    walk[..., 1] += np.linspace(0.0, 2.0, frames)[:, None]
    assert hyp.backward_travel(walk, JOINT_NAMES) == 0.0
    back = joints.copy()
    back[..., 1] -= np.linspace(0.0, 2.0, frames)[:, None]
    assert hyp.backward_travel(back, JOINT_NAMES) == pytest.approx(1.0, abs=0.01)
    short = joints.copy()
    short[..., 1] -= np.linspace(0.0, 0.25, frames)[:, None]  # a quarter metre: a shuffle, weighed by its length
    assert 0.15 < hyp.backward_travel(short, JOINT_NAMES) < 0.3
    assert hyp.backward_travel(joints, JOINT_NAMES) == 0.0


def test_placements_are_kept_by_chamfer_once_per_facing_and_handedness():
    def c(chamfer, yaw, mirror=False):
        return {"chamfer": chamfer, "matched_yaw_deg": yaw, "mirror": mirror}

    candidates = [c(1.0, 10.0), c(1.1, 40.0), c(1.2, 350.0, True), c(1.3, 190.0), c(1.4, 100.0), c(1.5, 200.0)]
    kept = hyp.distinct(candidates, 4, 45.0)
    assert [k["chamfer"] for k in kept] == [1.0, 1.2, 1.3, 1.4]  # 40 faces as 10 does; 350 mirrored is apart
    assert hyp.angle_deg(350.0, 10.0) == pytest.approx(20.0) and hyp.angle_deg(0.0, 180.0) == 180.0
    assert list(hyp.yaws(30.0)) == [float(y) for y in range(0, 360, 30)]
    with pytest.raises(hyp.HypothesisError, match="step_deg <= 30"):
        hyp.ScreenConfig(step_deg=45.0)

"""Skeleton calibration: reflector subsets are anatomical; the coarse scale follows the subject; the
calibrated skeleton puts the joints where the subject's are, from noisy reflectors of a studio motion."""


import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from mocapflow.tasks.deepmocap import poses, skeleton
from mocapflow.tasks.deepmocap.poses import forward_kinematics, reflector_positions
from mocapflow.tasks.shared import body, kinematics, reflectors
from mocapflow.tasks.studio import motion

NAMES = list(reflectors.REFLECTOR_NAMES)


def _recording(exercise, seed, n=90, noise=0.003, subject=None):
    rng = np.random.default_rng(seed)
    subject = subject or body.random_subject(rng)
    prims = body.surface(subject)
    placements = reflectors.place(prims, rng)
    m = motion.exercise(exercise, subject, n_frames=n)
    rot, pos = kinematics.forward_kinematics(m.local_rot, m.root_pos, body.rest_offsets(subject), body.PARENTS)
    xyz = reflectors.world_positions(placements, prims, rot, pos) + rng.normal(0, noise, (n, 26, 3))
    return subject, xyz, pos


def test_reflector_subsets_are_anatomical():
    assert skeleton.REFLECTOR_SUBSETS["LeftShoulder"] == ("F_L_SHOULDER", "B_L_SHOULDER")
    assert skeleton.REFLECTOR_SUBSETS["RightKnee"] == ("R_CALF",)
    assert skeleton.REFLECTOR_SUBSETS["Hips"] == ("F_SPINEMID", "B_SPINEMID", "R_PELVIS", "L_PELVIS")
    tmpl = skeleton.template(NAMES)
    left = [r for r, n in enumerate(NAMES) if n.startswith(("L_", "F_L_", "B_L_"))]
    assert all(tmpl.reflector_offsets[r, 0] + forward_kinematics(np.zeros((1, 40)), tmpl.offsets)[1][0, tmpl.bones[r], 0]
               < 0 for r in left)  # the subject's left is -x in the rest pose


def test_coarse_scale_follows_the_subject():
    subject, xyz, _ = _recording("walking_on_the_spot", seed=11)
    scale = skeleton.coarse_scale(xyz[:30], NAMES, skeleton.template(NAMES))
    true = (subject.height / skeleton.TEMPLATE_HEIGHT) * np.mean([subject.arm_scale, subject.leg_scale])
    assert abs(scale[0] - true) < 0.05, (scale[0], true)


def _bone_length_errors(scale, subject):
    true = np.linalg.norm(body.rest_offsets(subject), axis=1)[1:]
    fitted = np.linalg.norm(skeleton.template(NAMES).offsets * scale[:, None], axis=1)[1:]
    return np.abs(fitted / true - 1)  # (joint - root,) relative


@pytest.mark.parametrize("wild", [False, True])
def test_segment_scales_follow_the_subjects_proportions(wild):
    """Long arms, short legs, broad shoulders: the coarse scale (one number from the forearm and shin
    straps) cannot follow them; the segment fit moves the bones towards them (each segment is pulled to
    the common scale, so it goes part of the way), also when one reflector is 50 cm off in a few frames."""
    subject = body.Subject(height=1.68, arm_scale=1.07, leg_scale=0.94, torso_scale=1.03, shoulder_scale=1.08)
    _, xyz, _ = _recording("kick_box_kicking", seed=5, subject=subject)
    if wild:
        xyz[10:16, NAMES.index("L_CALF")] += [0.5, 0.0, 0.0]
    tmpl = skeleton.template(NAMES)
    coarse = skeleton.coarse_scale(xyz[:30], NAMES, tmpl)
    scale, refl_scale, _ = skeleton.fit_segment_scales(xyz[::2], tmpl, coarse, rounds=3, prior_m=3.0, outlier_m=0.03)
    fitted, before = _bone_length_errors(scale, subject), _bone_length_errors(coarse, subject)
    assert np.mean(fitted) < 0.8 * np.mean(before) and fitted.max() < 0.09, (fitted.round(3), before.round(3))
    arm = [body.JOINT_NAMES.index(n) for n in ("LeftElbow", "LeftWrist")]
    leg = [body.JOINT_NAMES.index(n) for n in ("LeftKnee", "LeftAnkle")]
    assert scale[arm].min() > scale[leg].max()  # the arms came out longer than the legs, relative to the template
    forearm = NAMES.index("L_WRIST")  # a strap scales with the segment it sits on
    assert refl_scale[forearm] == scale[body.JOINT_NAMES.index("LeftWrist")]


def test_skeleton_config_refuses_bad_scale_settings():
    with pytest.raises(ValueError, match="scale_rounds"):
        skeleton.SkeletonConfig(scale_rounds=-1)
    with pytest.raises(ValueError, match="scale_prior_m"):
        skeleton.SkeletonConfig(scale_prior_m=0.0)


def test_calibrated_skeleton_places_the_joints():
    subject, xyz, truth = _recording("kick_box_kicking", seed=4)
    conf = np.ones(xyz.shape[:2])
    config = skeleton.SkeletonConfig(frames=40, particles=300)
    offsets, bones, refl, scale, used = skeleton.calibrate(xyz, conf, NAMES, config)
    assert used == 40 and scale.shape == (20,)
    params, _, _ = poses.solve_sequence(xyz, conf, offsets, bones, refl, poses.PoseConfig())
    _, solved = forward_kinematics(params, offsets)
    err = np.linalg.norm(solved - truth, axis=-1)
    assert np.median(err) < 0.03 and np.percentile(err, 95) < 0.08, (np.median(err), np.percentile(err, 95))
    rot, pos = forward_kinematics(params, offsets)
    fit = np.linalg.norm(reflector_positions(rot, pos, bones, refl) - xyz, axis=-1)
    assert np.median(fit) < 0.01


def test_no_data_gives_the_template():
    xyz = np.full((10, 26, 3), np.nan)
    offsets, _, _, scale, used = skeleton.calibrate(xyz, np.zeros((10, 26)), NAMES, skeleton.SkeletonConfig())
    assert used == 0 and (scale == 1.0).all()
    np.testing.assert_allclose(offsets, body.rest_offsets(body.Subject(height=1.75)))


def test_rigidity_cost_is_not_outweighed_by_a_few_wrong_frames():
    """Eq. (11) finds the joint as the point of the parent's frame that keeps a constant distance to the
    child's reflector. Three frames of that reflector 60 cm off must not make a particle 10 cm from the
    joint look more rigid than the joint (they do under the plain variance)."""
    rng = np.random.default_rng(0)
    frames = 40
    t = np.linspace(0.0, 1.0, frames)
    child = Rotation.from_rotvec(np.column_stack([0.8 * np.sin(2 * np.pi * t), 0.6 * np.cos(2 * np.pi * t),
                                                  0.4 * t])).as_matrix()  # the child bone swings about the joint
    joint, local = np.array([0.3, 0.0, 0.0]), np.array([0.25, 0.03, 0.0])
    targets = (joint + child @ local)[:, None] + rng.normal(0.0, 0.003, (frames, 1, 3))
    targets[[5, 17, 30], 0] += [0.6, 0.0, 0.0]  # a mislabelled reflector for three frames
    world = np.broadcast_to(np.stack([joint, joint + [0.1, 0.0, 0.0]]), (frames, 2, 3))  # parent frame = world
    robust = skeleton.rigidity_cost(world, targets, outlier_m=0.03)
    assert robust[0] < robust[1]
    plain = skeleton.rigidity_cost(world, targets, outlier_m=np.inf)
    assert plain[0] > plain[1]  # ... the wrong particle wins without the cap


def test_skeleton_config_refuses_a_non_positive_outlier_cap():
    with pytest.raises(ValueError, match="outlier_m"):
        skeleton.SkeletonConfig(outlier_m=0.0)


def test_only_reflectors_side_by_side_on_the_body_are_neighbours():
    names = ["F_R_HEAD", "F_L_HEAD", "R_HAND", "L_HAND", "R_WRIST"]
    table = skeleton.neighbours(names, 0.10)
    assert table[0, 1] and table[1, 0]  # the forehead patches, 6 cm apart
    assert not table[2, 3] and not table[2, 4]  # the two hands; a hand and its wrist strap (11 cm)
    assert table.diagonal().all() and skeleton.neighbours(names, 0.0) is None


def test_rigidity_cost_median_is_numpys_nanmedian_bit_for_bit():
    from mocapflow.tasks.deepmocap import skeleton as sk

    rng = np.random.default_rng(8)
    d = rng.uniform(0, 1, (31, 40, 5))
    d[rng.uniform(size=d.shape) < 0.3] = np.nan
    d[:, 0, 0] = np.nan
    d[1:, 0, 0] = 0.25  # a column of one value (odd and even counts follow from the random NaNs)
    n = np.isfinite(d).sum(0)
    np.testing.assert_array_equal(sk._nanmedian_first(d, n), np.nanmedian(d, axis=0))

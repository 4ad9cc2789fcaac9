"""Skeleton calibration: reflector subsets are anatomical; the coarse scale follows the subject; the
calibrated skeleton puts the joints where the subject's are, from noisy reflectors of a studio motion."""

from dataclasses import asdict

import numpy as np

from mocapflow.tasks import poses, skeleton
from mocapflow.tasks.poses import forward_kinematics, reflector_positions
from mocapflow.tasks.studio import body, motion, reflectors

NAMES = list(reflectors.REFLECTOR_NAMES)


def _recording(exercise, seed, n=90, noise=0.003):
    rng = np.random.default_rng(seed)
    subject = body.random_subject(rng)
    prims = body.surface(subject)
    placements = reflectors.place(prims, rng)
    m = motion.exercise(exercise, subject, n_frames=n)
    rot, pos = body.forward_kinematics(m.local_rot, m.root_pos, body.rest_offsets(subject))
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


def test_calibrated_skeleton_places_the_joints():
    subject, xyz, truth = _recording("kick_box_kicking", seed=4)
    conf = np.ones(xyz.shape[:2])
    config = asdict(skeleton.SkeletonConfig(frames=40, particles=300))
    offsets, bones, refl, scale, used = skeleton.calibrate(xyz, conf, NAMES, **config)
    assert used == 40 and scale.shape == (20,)
    params, _, _ = poses.solve_sequence(xyz, conf, offsets, bones, refl, **asdict(poses.PoseConfig()))
    _, solved = forward_kinematics(params, offsets)
    err = np.linalg.norm(solved - truth, axis=-1)
    assert np.median(err) < 0.03 and np.percentile(err, 95) < 0.08, (np.median(err), np.percentile(err, 95))
    rot, pos = forward_kinematics(params, offsets)
    fit = np.linalg.norm(reflector_positions(rot, pos, bones, refl) - xyz, axis=-1)
    assert np.median(fit) < 0.01


def test_no_data_gives_the_template():
    xyz = np.full((10, 26, 3), np.nan)
    offsets, _, _, scale, used = skeleton.calibrate(xyz, np.zeros((10, 26)), NAMES,
                                                    **asdict(skeleton.SkeletonConfig()))
    assert used == 0 and (scale == 1.0).all()
    np.testing.assert_allclose(offsets, body.rest_offsets(body.Subject(height=1.75)))

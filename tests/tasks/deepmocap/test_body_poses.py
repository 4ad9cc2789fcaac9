"""The body fit of the reflectors (tasks/deepmocap/body_poses.py): Anny posed from DeepMoCap's 26 reflectors."""

from __future__ import annotations

import numpy as np
import pytest
import torch
import xarray as xr
from scipy.spatial.transform import Rotation

from mocapflow.schemas.skeleton import BODY_POSES
from mocapflow.tasks.deepmocap import body_poses as bp
from mocapflow.tasks.shared.body_fit import place_weights
from mocapflow.tasks.shared.place_fit import reference_body

FRAMES = 16
MOVED = {"upperarm01.L": (0.0, 0.6, 0.3), "lowerarm01.L": (0.0, 0.0, 0.9), "upperarm01.R": (0.3, -0.5, 0.0),
         "lowerarm01.R": (0.0, 0.0, -0.7), "upperleg01.L": (0.5, 0.0, 0.0), "lowerleg01.L": (-0.8, 0.0, 0.0),
         "upperleg01.R": (-0.3, 0.0, 0.1), "spine03": (0.15, 0.0, 0.1)}


def performed(phenotype, places, shift=None):
    """A take of Anny (``phenotype``) moving arms, legs and spine; the reflectors at ``places`` (shifted on the rest
    body by ``shift`` (place, 3) where given) and the 20 joints.  -> points (frame, place, 3), joints (frame, 20, 3)"""
    body = reference_body()
    local = np.tile(np.eye(3), (FRAMES, body.n_bones, 1, 1))
    phase = np.sin(np.linspace(0, np.pi, FRAMES))
    for name, rotvec in MOVED.items():
        local[:, body.body.bone(name)] = Rotation.from_rotvec(np.outer(phase, rotvec)).as_matrix()
    local[:, 0] = Rotation.from_rotvec(np.outer(np.linspace(0, 1.2, FRAMES), [0, 0, 1])).as_matrix()
    root = np.column_stack([np.linspace(0, 0.4, FRAMES), np.zeros(FRAMES), np.full(FRAMES, 1.0)])
    rest_vertices, rest_heads = body.rest_fixed(phenotype)
    rots, heads = body.kinematics(torch.from_numpy(local), torch.from_numpy(root), rest_heads)
    rest = (torch.from_numpy(places.blend)[..., None] * rest_vertices[torch.from_numpy(places.vertices)]).sum(1)
    if shift is not None:
        rest = rest + torch.from_numpy(shift)
    points = body.skin_dense(rots, heads, rest, rest_heads, torch.from_numpy(place_weights(body, places))).numpy()
    return points, heads.numpy()[:, body.body.joint_bones()]


def markers(points, confidence=None):
    confidence = np.ones(points.shape[:2]) if confidence is None else confidence
    return xr.Dataset({"position": (("frame", "reflector", "xyz"), points.astype(np.float32)),
                       "confidence": (("frame", "reflector"), confidence.astype(np.float32))},
                      coords={"frame": np.arange(len(points)), "reflector": list(bp.PLACE_NAMES),
                              "xyz": ["x", "y", "z"]}, attrs={"fps": 30.0})


PHENOTYPE = np.array([0.35, 0.6, 0.55, 0.45, 0.5, 0.5])


def test_the_body_is_found_from_its_reflectors_at_their_places():
    points, joints = performed(PHENOTYPE, bp.nominal_places(bp.PLACE_NAMES))
    solved = bp.fit_body_poses(markers(points), bp.BodyPoseConfig(calibration_rounds=0))
    BODY_POSES.validate(solved)
    error = np.linalg.norm(solved["position"].values - joints, axis=-1)
    assert np.median(error) < 0.01 and error.max() < 0.04  # exact places: the joints within a centimetre or so
    assert float(np.nanmax(solved["rms_error"])) < 0.005  # the body passes through its reflectors
    assert solved["fitted"].values.all() and (solved["reflectors"].values == 26).all()
    assert np.abs(solved["reflector_position"].values - points).max() < 0.02


def test_lost_and_doubtful_reflectors_are_left_out_and_lost_frames_borrow_their_neighbours():
    points, joints = performed(PHENOTYPE, bp.nominal_places(bp.PLACE_NAMES))
    confidence = np.ones(points.shape[:2])
    points[5:9, :20] = np.nan  # four frames keep 6 reflectors: fewer than min_points, borrowed
    points[12, 3] += 0.5  # a wrong position held at low confidence
    confidence[12, 3] = 0.01
    solved = bp.fit_body_poses(markers(points, confidence), bp.BodyPoseConfig(calibration_rounds=0))
    assert not solved["fitted"].values[5:9].any() and solved["fitted"].values[[4, 9]].all()
    assert solved["reflectors"].values[12] == 25
    error = np.linalg.norm(solved["position"].values - joints, axis=-1)  # (frame, joint)
    assert np.median(error[12]) < 0.015  # the doubtful reflector did not pull the body
    assert np.median(error[5:9]) < 0.05  # borrowed frames lie between their neighbours' poses


def test_calibrating_the_places_brings_back_reflectors_worn_elsewhere():
    places = bp.nominal_places(bp.PLACE_NAMES)
    shift = np.random.default_rng(3).normal(0.0, 0.015, (26, 3))  # each worn 1.5 cm (per axis) off its place
    points, joints = performed(PHENOTYPE, places, shift)
    errors = {}
    for rounds in (0, 3):
        solved = bp.fit_body_poses(markers(points), bp.BodyPoseConfig(calibration_rounds=rounds))
        errors[rounds] = float(np.mean(np.linalg.norm(solved["position"].values - joints, axis=-1)))
    assert errors[3] < 0.88 * errors[0]  # measured 0.84: a place moves on the skin, not off it; without calibration 1.0


def test_reflectors_without_a_place_and_bad_settings_are_refused_by_name_and_a_take_without_reflectors_is_unfitted():
    points, _ = performed(PHENOTYPE, bp.nominal_places(bp.PLACE_NAMES))
    odd = markers(points).assign_coords(reflector=["X_KNEE"] + list(bp.PLACE_NAMES[1:]))
    with pytest.raises(bp.BodyPoseError, match="X_KNEE"):
        bp.fit_body_poses(odd, bp.BodyPoseConfig())
    with pytest.raises(bp.BodyPoseError, match="calibration_rounds"):
        bp.BodyPoseConfig(calibration_rounds=-1)
    lost = bp.fit_body_poses(markers(np.full_like(points, np.nan)), bp.BodyPoseConfig())  # nothing to pose by
    assert not lost["fitted"].values.any() and np.isnan(lost["position"].values).all()


def test_the_fitted_body_exports_as_a_bvh_whose_joints_are_the_fitted_ones(tmp_path):
    from mocapflow.formats.bvh import read_bvh_joints
    from mocapflow.systems.deepmocap.export import write_bvh

    points, _ = performed(PHENOTYPE, bp.nominal_places(bp.PLACE_NAMES))
    solved = bp.fit_body_poses(markers(points), bp.BodyPoseConfig(calibration_rounds=0))
    write_bvh(solved, tmp_path / "take.bvh")
    joints, names, fps = read_bvh_joints(tmp_path / "take.bvh")
    assert fps == pytest.approx(30.0) and len(names) == solved.sizes["bone"]
    rig = reference_body().body
    heads = joints[:, [names.index(b.replace(".", "_")) for b in rig.bone_names]]  # the file's forward kinematics
    np.testing.assert_allclose(heads[:, rig.joint_bones()], solved["position"].values, atol=2e-4)  # float32 joints

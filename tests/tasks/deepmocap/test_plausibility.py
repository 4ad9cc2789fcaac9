"""Plausibility of the smoothed markers: a marker outside the sensors' capture volume or off its reflector on the
solved pose is removed with its reason; a plausible one is kept unchanged. The template body stands in the
default studio ring (three Kinect v2 2.5 m out, 0.8 m high) in its rest pose, the pose solved exactly."""

import numpy as np
import pytest
import xarray as xr
from scipy.spatial.transform import Rotation

from mocapflow.tasks.deepmocap import plausibility
from mocapflow.tasks.deepmocap.plausibility import KEPT, OFF_BODY, OUTSIDE_VOLUME, PlausibilityConfig
from mocapflow.tasks.deepmocap.poses import N_DOF, forward_kinematics
from mocapflow.tasks.deepmocap.skeleton import template
from mocapflow.tasks.shared.body import JOINT_NAMES, PARENTS
from mocapflow.tasks.shared.reflectors import REFLECTOR_TABLE
from mocapflow.tasks.studio.cameras import layout

NAMES = [name for name, *_ in REFLECTOR_TABLE]
ROOT = np.array([0.0, 0.0, 1.0])  # the pelvis 1 m up: the template's feet on the floor


def _scene(n_frames: int = 4):
    """smoothed markers on the posed template, its poses, skeleton and the studio ring's calibration."""
    tmpl = template(NAMES)
    params = np.zeros((1, N_DOF))
    params[0, :3] = ROOT
    rot, pos = forward_kinematics(params, tmpl.offsets)
    truth = np.einsum("rij,rj->ri", rot[0, tmpl.bones], tmpl.reflector_offsets) + pos[0, tmpl.bones]  # (R, 3)
    frames = np.arange(n_frames)
    markers = xr.Dataset(
        {"position": (("frame", "reflector", "xyz"), np.repeat(truth[None], n_frames, 0).astype(np.float32)),
         "confidence": (("frame", "reflector"), np.full((n_frames, len(NAMES)), 0.9, np.float32)),
         "predicted": (("frame", "reflector"), np.zeros((n_frames, len(NAMES)), bool))},
        coords={"frame": frames, "reflector": NAMES, "xyz": ["x", "y", "z"]},
        attrs={"fps": 30.0, "length_unit": "m", "up_axis": "Z", "smoothing": "kalman"})
    quat = np.tile(Rotation.identity().as_quat(), (n_frames, len(JOINT_NAMES), 1))
    poses = xr.Dataset({"position": (("frame", "joint", "xyz"), np.repeat(pos, n_frames, 0)),
                        "rotation": (("frame", "joint", "quat"), quat)},
                       coords={"frame": frames, "joint": list(JOINT_NAMES)})
    skeleton = xr.Dataset({"parent": (("joint",), PARENTS), "bone": (("reflector",), tmpl.bones),
                           "reflector_offset": (("reflector", "xyz"), tmpl.reflector_offsets)},
                          coords={"joint": list(JOINT_NAMES), "reflector": NAMES})
    cams = layout()
    calibration = xr.Dataset(
        {"fx": (("view",), [c.fx for c in cams]), "fy": (("view",), [c.fy for c in cams]),
         "cx": (("view",), [c.cx for c in cams]), "cy": (("view",), [c.cy for c in cams]),
         "dist": (("view", "k"), [list(c.dist) for c in cams]),
         "width": (("view",), [c.width for c in cams]), "height": (("view",), [c.height for c in cams]),
         "cam_to_world": (("view", "r", "c"), np.stack([c.cam_to_world for c in cams]))},
        coords={"view": [c.name for c in cams]})
    return markers, poses, skeleton, calibration, truth


def test_a_flying_marker_and_one_on_the_wrong_side_are_removed_plausible_ones_kept():
    markers, poses, skeleton, calibration, truth = _scene()
    head, wrist = NAMES.index("F_L_HEAD"), NAMES.index("L_WRIST")
    position = markers["position"].values.copy()
    position[0, head] = [-0.075, -3.414, 3.051]  # the demo's flying F_L_HEAD: 3.7 m off, above and behind the ring
    position[1, wrist] = truth[NAMES.index("R_WRIST")]  # on the other arm: inside the volume, 1.5 m off the body
    position[2, wrist] += [0.0, 0.0, 0.05]  # 5 cm off: noise, kept
    out = plausibility.check_markers(markers.assign(position=(markers["position"].dims, position)), poses, skeleton,
                                     calibration, PlausibilityConfig())
    rejected = out["rejected"].values
    assert rejected[0, head] == OUTSIDE_VOLUME and rejected[1, wrist] == OFF_BODY
    assert (rejected != KEPT).sum() == 2
    assert np.isnan(out["position"].values[0, head]).all() and np.isnan(out["position"].values[1, wrist]).all()
    assert out["confidence"].values[0, head] == 0 and out["confidence"].values[1, wrist] == 0
    np.testing.assert_allclose(out["position"].values[2, wrist], truth[wrist] + [0, 0, 0.05], atol=1e-6)
    np.testing.assert_allclose(out["position"].values[3], truth, atol=1e-6)  # an untouched frame
    assert (out.attrs["rejected_volume"], out.attrs["rejected_body"], out.attrs["unposed_frames"]) == (1, 1, 0)


def test_an_unsolved_frame_is_checked_against_the_volume_only():
    markers, poses, skeleton, calibration, truth = _scene(2)
    poses["position"][1] = np.nan
    poses["rotation"][1] = np.nan
    position = markers["position"].values.copy()
    position[1, 0] += [0.4, 0.0, 0.0]  # off the body, but no pose to tell
    position[1, 1] = [0.0, 0.0, -0.5]  # under the floor
    out = plausibility.check_markers(markers.assign(position=(markers["position"].dims, position)), poses, skeleton,
                                     calibration, PlausibilityConfig())
    assert out["rejected"].values[1, 0] == KEPT and out["rejected"].values[1, 1] == OUTSIDE_VOLUME
    assert out.attrs["unposed_frames"] == 1


def test_frustum_depth_range_and_image_bounds():
    # a camera at the origin looking along +z (identity pose), 100 px focal length, 200 x 100 image
    K = np.array([[100.0, 0.0, 100.0], [0.0, 100.0, 50.0], [0.0, 0.0, 1.0]])
    points = np.array([[0.0, 0.0, 2.0],  # centre
                       [0.0, 0.0, 0.3],  # nearer than near_m
                       [0.0, 0.0, 5.0],  # farther than far_m
                       [1.9, 0.0, 2.0],  # u = 195: inside
                       [2.1, 0.0, 2.0],  # u = 205: outside
                       [0.0, 0.0, -2.0]])  # behind
    inside = plausibility.in_frustum(points, np.eye(4), K, (200, 100), near_m=0.5, far_m=4.5)
    assert inside.tolist() == [True, False, False, True, False, False]
    assert plausibility.in_frustum(points, np.eye(4), K, (0, 0), near_m=0.5, far_m=4.5).tolist() == \
        [True, False, False, True, True, False]  # image size unknown: depth only


def test_config_rejects_an_empty_volume():
    with pytest.raises(ValueError, match="ceiling_m"):
        PlausibilityConfig(floor_m=1.0, ceiling_m=0.5)

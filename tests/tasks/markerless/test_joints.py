"""BlazePose's landmarks read as the template's 20 joints (tasks/markerless/joints.py), on a synthetic skeleton:
landmarks placed where BlazePose puts them on Anny's joints map back onto those joints."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from mocapflow.tasks.markerless.blazepose import LANDMARK_NAMES
from mocapflow.tasks.markerless.joints import MAPPING, template_joints
from mocapflow.tasks.shared.body import JOINT_NAMES
from mocapflow.tasks.shared.mesh_body import Phenotype, mesh_body


def synthetic_landmarks(joints: np.ndarray, lateral: np.ndarray, forward: np.ndarray) -> np.ndarray:
    """BlazePose's 33 landmarks of a skeleton (20 template joints): the limbs' on their joints, the ears either side
    of the head, the hand's knuckles either side of its end, heel and toe tip round the foot's joint; the face's
    landmarks at the head."""
    j = {n: joints[i] for i, n in enumerate(JOINT_NAMES)}
    lm = {name: j["Head"] + 0.08 * forward for name in LANDMARK_NAMES}
    for side, s in (("left", -1.0), ("right", 1.0)):  # the template's left is -x in its own frame
        S = side.capitalize()
        for part, joint in (("shoulder", "Shoulder"), ("elbow", "Elbow"), ("wrist", "Wrist"), ("hip", "Hip"),
                            ("knee", "Knee"), ("ankle", "Ankle")):
            lm[f"{side}_{part}"] = j[S + joint]
        lm[f"{side}_ear"] = j["Head"] + s * 0.075 * lateral
        lm[f"{side}_index"] = j[S + "Hand"] + 0.02 * forward
        lm[f"{side}_pinky"] = j[S + "Hand"] - 0.02 * forward
        lm[f"{side}_thumb"] = j[S + "Hand"] + 0.03 * forward
        along = j[S + "Foot"] - j[S + "Ankle"]
        lm[f"{side}_heel"] = j[S + "Foot"] - 0.7 * 2.0 * along  # the toes' base 0.7 of the way heel -> tip
        lm[f"{side}_foot_index"] = j[S + "Foot"] + 0.3 * 2.0 * along
    return np.stack([lm[n] for n in LANDMARK_NAMES])


def test_the_map_reads_a_synthetic_skeleton_back():
    body = mesh_body(Phenotype())
    rest = body.rest_heads[body.joint_bones()]  # (20, 3), JOINT_NAMES order, facing +Y, left at -x
    turn = Rotation.from_euler("zx", [37.0, 8.0], degrees=True).as_matrix()
    joints = rest @ turn.T + [0.4, -0.2, 0.05]  # turned, tilted and moved
    landmarks = synthetic_landmarks(joints, turn @ [1.0, 0.0, 0.0], turn @ [0.0, 1.0, 0.0])
    mapped, conf = template_joints(landmarks)
    error_mm = 1000 * np.linalg.norm(mapped - joints, axis=1)
    per_joint = dict(zip(JOINT_NAMES, error_mm))
    # the limbs' joints are BlazePose's own landmarks, the hands and feet their midpoints: exact
    exact = [n for n in JOINT_NAMES if n not in ("Hips", "SpineBase", "Neck")]
    assert max(per_joint[n] for n in exact) < 1e-6, per_joint
    # the trunk's, from midpoints: measured 16.3 mm for the hips' midpoint from Anny's root (13 mm below, 9 mm
    # behind) and 16.1 mm for the neck on the trunk's line (its height right, 16 mm before Anny's neck: the
    # shoulders stand 21 mm before the hips)
    assert per_joint["Hips"] < 20.0 and per_joint["SpineBase"] < 20.0 and per_joint["Neck"] < 20.0, per_joint
    assert abs(mapped[JOINT_NAMES.index("Neck")] - joints[JOINT_NAMES.index("Neck")]) @ (turn @ [0, 0, 1.0]) < 0.003
    assert (conf == 1.0).all()
    # the same map on 2D landmarks (a projection's x, z) gives the joints' projections: it is linear
    flat, _ = template_joints(landmarks[:, [0, 2]])
    assert np.allclose(flat, mapped[:, [0, 2]])
    # each joint reads the landmarks its documentation names, weights summing to one
    assert MAPPING["Head"] == {"left_ear": 0.5, "right_ear": 0.5}
    assert MAPPING["LeftKnee"] == {"left_knee": 1.0} and MAPPING["RightWrist"] == {"right_wrist": 1.0}


def test_a_missing_landmark_loses_only_the_joints_that_read_it_and_confidence_is_the_least():
    rng = np.random.default_rng(0)
    landmarks = rng.normal(0.0, 0.5, (2, 33, 3))
    conf = rng.uniform(0.5, 1.0, (2, 33))
    landmarks[1, LANDMARK_NAMES.index("left_shoulder")] = np.nan
    joints, joint_conf = template_joints(landmarks, conf)
    lost = {JOINT_NAMES[j] for j in np.flatnonzero(np.isnan(joints[1]).any(axis=1))}
    assert lost == {"LeftShoulder", "Neck"}
    assert np.isfinite(joints[0]).all() and (joint_conf[1][[JOINT_NAMES.index(n) for n in lost]] == 0).all()
    head = JOINT_NAMES.index("Head")
    assert joint_conf[0, head] == min(conf[0, LANDMARK_NAMES.index("left_ear")], conf[0, LANDMARK_NAMES.index("right_ear")])

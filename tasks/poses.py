"""Pose solving on the calibrated template (DeepMoCap §3.5, "motion capture"): per frame, the 40
joint degrees of freedom of Figure 9a that put the calibrated reflector offsets onto the 3D optical data.

Parameters (``DOF_AXES``): the root's rotation vector and translation (6), then per joint the
rotation-vector components it may use: 3 for ball joints (spine, neck, shoulders, hips), 2 for the
head (nod, turn) and for elbows, wrists and ankles (swing of the child bone), 1 for the knees
(flexion), none for the end joints (hands, feet). Bone lengths are fixed by the skeleton.

Each frame is a nonlinear least-squares problem (scipy ``least_squares``, Levenberg-Marquardt):
residuals are the confidence-weighted reflector errors of the reflectors seen in that frame, plus
a small pull towards the previous frame's parameters, so a joint whose reflectors are all missing
keeps its last rotation instead of drifting. Frames are warm-started from the previous solution.
The Jacobian is a batched forward difference: one vectorized forward kinematics for all 41 states.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import xarray as xr
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from mocapflow.tasks.studio.body import JOINT_NAMES, PARENTS

# joint -> rotation-vector components it may use (rest frames are world-aligned: x right, y forward, z up)
_AXES = {"Hips": "xyz", "SpineBase": "xyz", "Neck": "xyz", "Head": "xz", "Shoulder": "xyz", "Elbow": "yz",
         "Wrist": "yz", "Hand": "", "Hip": "xyz", "Knee": "x", "Ankle": "xz", "Foot": ""}
DOF_AXES = tuple(_AXES[n.removeprefix("Left").removeprefix("Right")] for n in JOINT_NAMES)
N_DOF = 3 + sum(len(a) for a in DOF_AXES)  # root translation + rotations
assert N_DOF == 40

# (40,) -> (joint * 3,) selection: rotation-vector component k of joint j is parameter SELECT[3j + k] (or none).
# DISTAL marks the wrists' and ankles' parameters: a strap sits on the limb axis, so the twist of a straight
# arm or leg and the swing of the hand or foot can trade off; these get the stronger pull to rest.
_SELECT = np.full(3 * len(JOINT_NAMES), -1)
DISTAL = np.zeros(N_DOF, bool)
_k = 3
for _j, _axes in enumerate(DOF_AXES):
    for _a in _axes:
        _SELECT[3 * _j + "xyz".index(_a)] = _k
        DISTAL[_k] = JOINT_NAMES[_j].endswith(("Wrist", "Ankle"))
        _k += 1
_USED = _SELECT >= 0


@dataclass(frozen=True)
class PoseConfig:
    min_confidence: float = 0.05  # reflectors below this confidence are treated as missing
    temporal_weight: float = 0.01  # metres of reflector error equivalent to one radian of change from the last frame
    rest_weight: float = 0.002  # the same, per radian from the rest pose: settles what no reflector sees
    distal_rest_weight: float = 0.02  # the same for wrists and ankles (see DISTAL)
    max_iterations: int = 50  # Levenberg-Marquardt function evaluations per frame (x 41 states)
    min_reflectors: int = 4  # fewer seen reflectors: the frame is not solved (NaN)


def rodrigues(rotvec: np.ndarray) -> np.ndarray:
    """Rotation matrices of rotation vectors.  (..., 3) -> (..., 3, 3)"""
    theta = np.linalg.norm(rotvec, axis=-1)[..., None, None]  # (..., 1, 1)
    safe = np.where(theta > 1e-12, theta, 1.0)
    k = rotvec / safe[..., 0]
    K = np.zeros(rotvec.shape[:-1] + (3, 3))
    K[..., 0, 1], K[..., 0, 2], K[..., 1, 2] = -k[..., 2], k[..., 1], -k[..., 0]
    K = K - np.swapaxes(K, -1, -2)
    sin, cos = np.sin(theta), np.cos(theta)
    return np.eye(3) + sin * K + (1 - cos) * (K @ K)  # Rodrigues' formula


def local_rotations(params: np.ndarray) -> np.ndarray:
    """Local joint rotations of parameter vectors.  (batch, 40) -> (batch, joint, 3, 3)"""
    rotvec = np.zeros(params.shape[:-1] + (3 * len(JOINT_NAMES),))
    rotvec[..., _USED] = params[..., _SELECT[_USED]]
    return rodrigues(rotvec.reshape(params.shape[:-1] + (len(JOINT_NAMES), 3)))


def forward_kinematics(params: np.ndarray, offsets: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """World rotations and positions of every joint.  (batch, 40), (joint, 3) -> (batch, joint, 3, 3), (batch, joint, 3)"""
    local = local_rotations(params)
    rot, pos = np.empty_like(local), np.empty(local.shape[:-1])
    for j, parent in enumerate(PARENTS):
        if parent < 0:
            rot[:, j], pos[:, j] = local[:, j], params[:, :3]
        else:
            rot[:, j] = rot[:, parent] @ local[:, j]
            pos[:, j] = pos[:, parent] + rot[:, parent] @ offsets[j]
    return rot, pos


def reflector_positions(rot: np.ndarray, pos: np.ndarray, bones: np.ndarray, reflector_offsets: np.ndarray) -> np.ndarray:
    """World positions of reflectors rigidly attached to bones.  (b, joint, 3, 3), (b, joint, 3) -> (b, reflector, 3)"""
    return np.einsum("brij,rj->bri", rot[:, bones], reflector_offsets) + pos[:, bones]


def rigid_fit(source: np.ndarray, target: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rotation and translation taking ``source`` onto ``target`` in the least-squares sense (Kabsch). (n, 3) x 2"""
    mu_s, mu_t = source.mean(0), target.mean(0)
    u, _, vt = np.linalg.svd((source - mu_s).T @ (target - mu_t))
    d = np.sign(np.linalg.det(vt.T @ u.T))
    r = vt.T @ np.diag([1.0, 1.0, d]) @ u.T
    return r, mu_t - r @ mu_s


def initial_params(observed: np.ndarray, offsets: np.ndarray, bones: np.ndarray,
                   reflector_offsets: np.ndarray) -> np.ndarray:
    """A rest pose placed and turned by the rigid fit of the seen trunk reflectors (or just placed).  (reflector, 3) -> (40,)"""
    params = np.zeros(N_DOF)
    rot, pos = forward_kinematics(params[None], offsets)  # the rest pose
    rest = reflector_positions(rot, pos, bones, reflector_offsets)[0]
    trunk = np.isin(bones, (0, 1)) & np.isfinite(observed).all(1)  # Hips and SpineBase reflectors
    seen = np.isfinite(observed).all(1)
    if trunk.sum() >= 3:
        r, t = rigid_fit(rest[trunk], observed[trunk])
        params[3:6] = Rotation.from_matrix(r).as_rotvec()
        params[:3] = t
    elif seen.any():
        params[:3] = observed[seen].mean(0) - rest[seen].mean(0)
    return params


def _residuals_batch(states, observed, weights, previous, offsets, bones, reflector_offsets, temporal_weight,
                     rest_weights):
    rot, pos = forward_kinematics(states, offsets)
    pred = reflector_positions(rot, pos, bones, reflector_offsets)  # (batch, seen, 3)
    fit = ((pred - observed) * weights[:, None]).reshape(len(states), -1)
    temporal = temporal_weight * (states[:, 3:] - previous[3:])  # rotations only; the root may travel
    rest = rest_weights[6:] * states[:, 6:]  # joint rotations (not the root's) towards the rest pose
    return np.concatenate([fit, temporal, rest], axis=1)


def solve_frame(observed: np.ndarray, weights: np.ndarray, start: np.ndarray, offsets: np.ndarray,
                bones: np.ndarray, reflector_offsets: np.ndarray, *, temporal_weight: float, rest_weights: np.ndarray,
                max_iterations: int) -> tuple[np.ndarray, float]:
    """Parameters fitting the seen reflectors of one frame, and the RMS reflector error.

    observed (seen, 3), weights (seen,), bones (seen,), reflector_offsets (seen, 3), start (40,), rest_weights (40,).
    """
    args = (observed, weights, start, offsets, bones, reflector_offsets, temporal_weight, rest_weights)
    step = 1e-6

    def fun(x):
        return _residuals_batch(x[None], *args)[0]

    def jac(x):
        states = np.vstack([x, x + step * np.eye(N_DOF)])  # (41, 40): forward differences in one batch
        r = _residuals_batch(states, *args)
        return ((r[1:] - r[0]) / step).T

    fit = least_squares(fun, start, jac=jac, method="lm", max_nfev=max_iterations, xtol=1e-8, ftol=1e-10)
    rot, pos = forward_kinematics(fit.x[None], offsets)
    err = reflector_positions(rot, pos, bones, reflector_offsets)[0] - observed
    return fit.x, float(np.sqrt(np.mean(np.sum(err**2, axis=1))))


def solve_sequence(position: np.ndarray, confidence: np.ndarray, offsets: np.ndarray, bones: np.ndarray,
                   reflector_offsets: np.ndarray, *, min_confidence: float, temporal_weight: float,
                   rest_weight: float, distal_rest_weight: float, max_iterations: int,
                   min_reflectors: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Parameters of every frame, warm-started from the previous solved frame.

    position (frame, reflector, 3) NaN where missing, confidence (frame, reflector)
    -> params (frame, 40) NaN where unsolved, rms error (frame,), reflectors used (frame,)
    """
    n = position.shape[0]
    params, rms, used = np.full((n, N_DOF), np.nan), np.full(n, np.nan), np.zeros(n, np.int16)
    previous = None
    rest_weights = np.where(DISTAL, distal_rest_weight, rest_weight)
    for i in range(n):
        seen = np.isfinite(position[i]).all(1) & (np.nan_to_num(confidence[i]) >= min_confidence)
        used[i] = seen.sum()
        if used[i] < min_reflectors:
            continue
        frame = (position[i, seen], np.sqrt(np.clip(confidence[i, seen], 0.0, 1.0)))
        rig = (offsets, bones[seen], reflector_offsets[seen])
        start = previous
        if start is None:  # first frame: from the rest pose, held near it first to avoid twisted minima
            start = initial_params(np.where(seen[:, None], position[i], np.nan), offsets, bones, reflector_offsets)
            start, _ = solve_frame(*frame, start, *rig, temporal_weight=0.0, rest_weights=10 * rest_weights,
                                   max_iterations=4 * max_iterations)
        params[i], rms[i] = solve_frame(*frame, start, *rig, temporal_weight=temporal_weight,
                                        rest_weights=rest_weights, max_iterations=max_iterations)
        previous = params[i]
    return params, rms, used


def solve_poses(skeleton: xr.Dataset, markers: xr.Dataset, *, min_confidence: float, temporal_weight: float,
                rest_weight: float, distal_rest_weight: float, max_iterations: int, min_reflectors: int) -> xr.Dataset:
    """`poses` stage: joint world positions and local rotations of every frame of a sequence."""
    names = [str(n) for n in markers["reflector"].values]
    skel = skeleton.sel(reflector=names)
    offsets = skel["offset"].values.astype(np.float64)
    params, rms, used = solve_sequence(
        markers["position"].values.astype(np.float64), markers["confidence"].values.astype(np.float64), offsets,
        skel["bone"].values.astype(int), skel["reflector_offset"].values.astype(np.float64),
        min_confidence=min_confidence, temporal_weight=temporal_weight, rest_weight=rest_weight,
        distal_rest_weight=distal_rest_weight, max_iterations=max_iterations,
        min_reflectors=min_reflectors)
    solved = np.isfinite(params).all(1)
    local = local_rotations(np.nan_to_num(params))  # (frame, joint, 3, 3)
    _, pos = forward_kinematics(np.nan_to_num(params), offsets)
    quat = Rotation.from_matrix(local.reshape(-1, 3, 3)).as_quat().reshape(local.shape[:2] + (4,))
    pos[~solved], quat[~solved] = np.nan, np.nan
    return xr.Dataset(
        {"position": (("frame", "joint", "xyz"), pos.astype(np.float32)),
         "rotation": (("frame", "joint", "quat"), quat.astype(np.float32)),
         "offset": (("joint", "xyz"), offsets.astype(np.float32)),
         "rms_error": (("frame",), rms.astype(np.float32)),
         "reflectors": (("frame",), used.astype(np.int16))},
        coords={"frame": markers["frame"].values, "joint": skeleton["joint"].values, "xyz": ["x", "y", "z"],
                "quat": ["x", "y", "z", "w"]},
        attrs={"length_unit": "m", "up_axis": "Z", "fps": float(markers.attrs["fps"])},
    )

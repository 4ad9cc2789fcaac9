"""Pose solving on the calibrated template (DeepMoCap §3.5, "motion capture"): per frame, the 40
joint degrees of freedom of Figure 9a that put the calibrated reflector offsets onto the 3D optical data.

Parameters (``DOF_AXES``): the root's rotation vector and translation (6), then per joint the
rotation-vector components it may use: 3 for ball joints (spine, neck, shoulders, hips), 2 for the
head (nod, turn) and for elbows, wrists and ankles (swing of the child bone), 1 for the knees
(flexion), none for the end joints (hands, feet). Bone lengths are fixed by the skeleton.

Each frame is a nonlinear least-squares problem (MINPACK's Levenberg-Marquardt through scipy ``leastsq``):
residuals are the confidence-weighted reflector errors of the reflectors seen in that frame, plus
a small pull towards the previous frame's parameters, so a joint whose reflectors are all missing
keeps its last rotation instead of drifting. Frames are warm-started from the previous solution.

Order and gate: the solve starts at an anchor frame, the first that sees at least the take's median
count of reflectors and whose reflectors keep the distances the skeleton allows (a take may open with
wrong labels), runs forward to the end, then backward from the anchor to the first frame. Each later frame leaves out
the reflectors that lie more than ``gate_m`` from where the last two solved frames' motion (constant
velocity) puts them, or that lie more than ``margin_m`` nearer another reflector's prediction than
their own: a label that jumps to another limb or to a neighbouring strap, or a limb that reappears under
the wrong label, does not pull the skeleton there; the limb holds its rotation until its reflectors come back.
Left-out reflectors that make up a limb on their own (two or more keeping the skeleton's distances) are
taken back at once, so a limb the solve has lost is found again. A reflector still without data takes a
single view's estimate (under any label) that lies within ``view_m`` of its prediction: where two views
swap the legs and one labels them right, fusion follows the two, and the one view's estimate remains.

The Jacobian is analytic: a rotation-vector step dθ of joint j turns everything below j about the
joint by ω = W_j J_r(θ_j) dθ (W_j the joint's world rotation, J_r the right Jacobian of SO(3)), so a
reflector at p moves by ω × (p − o_j).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import xarray as xr
from scipy.optimize import leastsq
from scipy.sparse.csgraph import connected_components
from scipy.spatial.transform import Rotation

from mocapflow.tasks.shared import kinematics
from mocapflow.tasks.shared.body import JOINT_NAMES, PARENTS
from mocapflow.tasks.shared.kinematics import cross, right_jacobian, rigid_fit, rodrigues

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
_ROT_SLOT = np.flatnonzero(_SELECT >= 3)  # rotation parameters 3..39 as (joint * 3 + axis) slots, in parameter order
assert (_SELECT[_ROT_SLOT] == np.arange(3, N_DOF)).all()
_ROT_JOINT, _ROT_AXIS = _ROT_SLOT // 3, _ROT_SLOT % 3


@dataclass(frozen=True)
class PoseConfig:
    min_confidence: float = 0.05  # reflectors below this confidence are treated as missing
    temporal_weight: float = 0.01  # metres of reflector error equivalent to one radian of change from the last frame
    rest_weight: float = 0.002  # the same, per radian from the rest pose: settles what no reflector sees
    distal_rest_weight: float = 0.02  # the same for wrists and ankles (see DISTAL)
    max_iterations: int = 20  # Levenberg-Marquardt function evaluations per frame (the first frame gets 4x more)
    min_reflectors: int = 4  # fewer seen reflectors: the frame is not solved (NaN)
    tolerance: float = 1e-4  # Levenberg-Marquardt stops at this relative change of the cost or of the step
    gate_m: float = 0.25  # a reflector this far from where the last two solved frames' motion puts it is left out; 0: off
    rigid_tolerance_m: float = 0.05  # how far reflector distances may stray from the skeleton's (anchor, take-back); 0: off
    margin_m: float = 0.05  # a reflector this much nearer another reflector's prediction than its own is left out; 0: off
    view_m: float = 0.05  # a reflector left without data takes a view's own estimate this near its prediction; 0: off

    def __post_init__(self):
        if self.max_iterations < 1:
            raise ValueError(f"max_iterations must be >= 1 function evaluations, e.g. 20, got {self.max_iterations}")
        if not 0 < self.tolerance < 1:
            raise ValueError(f"tolerance must lie in (0, 1), e.g. 1e-4, got {self.tolerance}")
        for name in ("gate_m", "rigid_tolerance_m", "margin_m", "view_m"):
            value = getattr(self, name)
            if not 0 <= value < 10:
                raise ValueError(f"{name} must lie in [0, 10) metres (0 turns it off), e.g. 0.25, got {value}")


def joint_rotvecs(params: np.ndarray) -> np.ndarray:
    """Each joint's local rotation vector (zero on the axes it may not use).  (batch, 40) -> (batch, joint, 3)"""
    rotvec = np.zeros(params.shape[:-1] + (3 * len(JOINT_NAMES),))
    rotvec[..., _USED] = params[..., _SELECT[_USED]]
    return rotvec.reshape(params.shape[:-1] + (len(JOINT_NAMES), 3))


def local_rotations(params: np.ndarray) -> np.ndarray:
    """Local joint rotations of parameter vectors.  (batch, 40) -> (batch, joint, 3, 3)"""
    return rodrigues(joint_rotvecs(params))


def _moves_table(parents: np.ndarray) -> np.ndarray:
    """(joint, joint) bool: row j marks j and every joint below it (what a rotation of j carries)."""
    table = np.eye(len(parents), dtype=bool)
    for j in range(len(parents)):
        a = parents[j]
        while a >= 0:
            table[a, j] = True
            a = parents[a]
    return table


_MOVES = _moves_table(PARENTS)


def forward_kinematics(params: np.ndarray, offsets: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """World rotations and positions of every joint.  (batch, 40), (joint, 3) -> (batch, joint, 3, 3), (batch, joint, 3)"""
    return kinematics.forward_kinematics(local_rotations(params), params[:, :3], offsets, PARENTS)


def reflector_positions(rot: np.ndarray, pos: np.ndarray, bones: np.ndarray, reflector_offsets: np.ndarray) -> np.ndarray:
    """World positions of reflectors rigidly attached to bones.  (b, joint, 3, 3), (b, joint, 3) -> (b, reflector, 3)"""
    return np.einsum("brij,rj->bri", rot[:, bones], reflector_offsets) + pos[:, bones]


def rest_pose_reflectors(offsets: np.ndarray, bones: np.ndarray, reflector_offsets: np.ndarray) -> np.ndarray:
    """World positions of reflectors on a skeleton in its rest pose (all parameters zero).  -> (reflector, 3)"""
    rot, pos = forward_kinematics(np.zeros((1, N_DOF)), offsets)
    return reflector_positions(rot, pos, bones, reflector_offsets)[0]


def initial_params(observed: np.ndarray, offsets: np.ndarray, bones: np.ndarray,
                   reflector_offsets: np.ndarray) -> np.ndarray:
    """A rest pose placed and turned by the rigid fit of the seen trunk reflectors (or just placed).  (reflector, 3) -> (40,)"""
    params = np.zeros(N_DOF)
    rest = rest_pose_reflectors(offsets, bones, reflector_offsets)
    trunk = np.isin(bones, (0, 1)) & np.isfinite(observed).all(1)  # Hips and SpineBase reflectors
    seen = np.isfinite(observed).all(1)
    if trunk.sum() >= 3:
        r, t = rigid_fit(rest[trunk], observed[trunk])
        params[3:6] = Rotation.from_matrix(r).as_rotvec()
        params[:3] = t
    elif seen.any():
        params[:3] = observed[seen].mean(0) - rest[seen].mean(0)
    return params


def pull(previous: np.ndarray, temporal_weight: float, rest_weights: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The pulls to the previous frame (rotations; the root may travel) and to rest (joint rotations, not
    the root's) as one residual row per pulled parameter: w_t²(x − p)² + w_r²x² = w²(x − m)² + const,
    with w² = w_t² + w_r² and m = w_t² p / w².  (40,) -> weights (k,), targets (k,), which parameters (40,) bool"""
    wt2 = np.where(np.arange(N_DOF) >= 3, temporal_weight**2, 0.0)
    wr2 = np.where(np.arange(N_DOF) >= 6, rest_weights**2, 0.0)
    rows = wt2 + wr2 > 0
    w2 = (wt2 + wr2)[rows]
    return np.sqrt(w2), wt2[rows] * previous[rows] / w2, rows


def _residuals(x, posed, observed, weights, bones, reflector_offsets, prior):
    """Weighted reflector errors, then the pulls of ``pull``.  (40,) -> (seen * 3 + k,)

    ``posed`` is ``forward_kinematics(x[None], offsets)``; ``prior`` is ``pull(...)``.
    """
    rot, pos = posed
    pred = reflector_positions(rot, pos, bones, reflector_offsets)[0]  # (seen, 3)
    fit = ((pred - observed) * weights[:, None]).ravel()
    w, target, rows = prior
    return np.concatenate([fit, w * (x[rows] - target)])


def _fit_jacobian(x: np.ndarray, posed: tuple[np.ndarray, np.ndarray], weights: np.ndarray, bones: np.ndarray,
                  reflector_offsets: np.ndarray) -> np.ndarray:
    """d(weighted reflector residuals)/d(params), analytic.  (40,) -> (seen * 3, 40); ``posed`` as in _residuals"""
    pred = reflector_positions(*posed, bones, reflector_offsets)[0]  # (seen, 3)
    rot, pos = posed[0][0], posed[1][0]  # (joint, 3, 3), (joint, 3)
    turn = rot[_ROT_JOINT] @ right_jacobian(joint_rotvecs(x)[_ROT_JOINT])  # (37, 3, 3): W_j J_r(θ_j)
    omega = turn[np.arange(len(_ROT_JOINT)), :, _ROT_AXIS]  # (37, 3): world axis of each rotation parameter
    arms = pred[None] - pos[_ROT_JOINT][:, None]  # (37, seen, 3): p - o_j
    moved = _MOVES[_ROT_JOINT][:, bones]  # (37, seen): the reflector's bone lies below joint j
    columns = cross(omega[:, None], arms) * moved[..., None]  # (37, seen, 3): ω x (p - o_j)
    jac = np.empty((len(bones), 3, N_DOF))
    jac[:, :, :3] = np.eye(3)  # root translation
    jac[:, :, 3:] = columns.transpose(1, 2, 0)
    return (jac * weights[:, None, None]).reshape(-1, N_DOF)


def solve_frame(observed: np.ndarray, weights: np.ndarray, start: np.ndarray, offsets: np.ndarray,
                bones: np.ndarray, reflector_offsets: np.ndarray, *, temporal_weight: float, rest_weights: np.ndarray,
                max_iterations: int, tolerance: float) -> tuple[np.ndarray, float]:
    """Parameters fitting the seen reflectors of one frame, and the RMS reflector error.

    observed (seen, 3), weights (seen,), bones (seen,), reflector_offsets (seen, 3), start (40,), rest_weights (40,).
    """
    prior = pull(start, temporal_weight, rest_weights)
    args = (observed, weights, bones, reflector_offsets, prior)
    pull_weights, _, pulled = prior
    regular = np.zeros((len(pull_weights), N_DOF))
    regular[np.arange(len(pull_weights)), np.flatnonzero(pulled)] = pull_weights  # d(pulls)/dx
    last: list = [None, None]  # x and its forward kinematics: the Jacobian is asked for where the residuals were

    def posed(x):
        if last[0] is None or not np.array_equal(last[0], x):
            last[:] = x.copy(), forward_kinematics(x[None], offsets)
        return last[1]

    def fun(x):
        return _residuals(x, posed(x), *args)

    def jac(x):
        return np.vstack([_fit_jacobian(x, posed(x), weights, bones, reflector_offsets), regular])

    # MINPACK's lmder as least_squares(method="lm") calls it (its default scaling, factor 100, gtol 1e-8), without
    # that wrapper's per-call bookkeeping: the same answers, the calibration a sixth faster
    x = leastsq(fun, start, Dfun=jac, full_output=True, ftol=tolerance, xtol=tolerance, gtol=1e-8,
                maxfev=max_iterations, factor=100.0)[0]
    err = reflector_positions(*posed(x), bones, reflector_offsets)[0] - observed
    return x, float(np.sqrt(np.mean(np.sum(err**2, axis=1))))


def distance_bounds(offsets: np.ndarray, bones: np.ndarray, reflector_offsets: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The least and greatest distance the skeleton allows between two reflectors on one bone (their fixed
    distance) or on a bone and its child (they turn about the joint between them); NaN for other pairs.

    offsets (joint, 3), bones (reflector,), reflector_offsets (reflector, 3) -> two (reflector, reflector)
    """
    n = len(bones)
    lo, hi = np.full((n, n), np.nan), np.full((n, n), np.nan)
    same = (bones[:, None] == bones[None]) & ~np.eye(n, dtype=bool)
    fixed = np.linalg.norm(reflector_offsets[:, None] - reflector_offsets[None], axis=-1)  # (a, b)
    lo[same], hi[same] = fixed[same], fixed[same]
    child = PARENTS[bones][None, :] == bones[:, None]  # (a, b): b's bone hangs from a's bone
    to_joint = np.linalg.norm(reflector_offsets[:, None] - offsets[bones][None], axis=-1)  # (a, b): a to b's joint
    own = np.broadcast_to(np.linalg.norm(reflector_offsets, axis=-1)[None], (n, n))  # (a, b): b to its joint
    lo[child], hi[child] = np.abs(to_joint - own)[child], (to_joint + own)[child]
    lo[child.T], hi[child.T] = lo.T[child.T], hi.T[child.T]
    return lo, hi


def within_bounds(points: np.ndarray, lo: np.ndarray, hi: np.ndarray, tolerance_m: float) -> np.ndarray:
    """Which pairs of points keep their distance within the bounds (pairs without bounds do).
    points (..., n, 3), lo and hi (n, n) -> (..., n, n) bool; NaN points agree with everything"""
    d = np.linalg.norm(points[..., :, None, :] - points[..., None, :, :], axis=-1)
    return ~((d < lo - tolerance_m) | (d > hi + tolerance_m))


ANCHOR_BLOCK = 256  # frames whose distance tables are built at once while looking for the anchor


def anchor_frame(position: np.ndarray, seen: np.ndarray, bounds: tuple[np.ndarray, np.ndarray], *,
                 tolerance_m: float, min_reflectors: int) -> int:
    """The frame the solve starts from: the first that sees at least as many reflectors as the take's median
    frame, and whose seen reflectors keep within ``tolerance_m`` of the skeleton's distance bounds
    (``distance_bounds``); 0 where none does or ``tolerance_m`` is 0.

    position (frame, reflector, 3), seen (frame, reflector) bool
    """
    count = seen.sum(1)  # (frame,)
    if tolerance_m <= 0 or count.max() < min_reflectors:
        return 0
    enough = np.flatnonzero(count >= max(np.median(count), min_reflectors))
    for block in np.array_split(enough, max(1, len(enough) // ANCHOR_BLOCK)):  # a long take is scanned in blocks
        points = np.where(seen[block, :, None], position[block], np.nan)  # (block, reflector, 3)
        ok = within_bounds(points, *bounds, tolerance_m).all(axis=(1, 2))  # (block,)
        if ok.any():
            return int(block[np.argmax(ok)])
    return 0


def take_back(position: np.ndarray, seen: np.ndarray, kept: np.ndarray, bounds: tuple[np.ndarray, np.ndarray], *,
              tolerance_m: float, coincide_m: float) -> np.ndarray:
    """``kept`` plus the left-out reflectors that make up a limb on their own: two or more, linked by bounds
    (one bone, or a bone and its child), every linked pair within ``tolerance_m`` of its bounds, none within
    ``coincide_m`` of a kept reflector (a copy of another label). A limb the solve has lost (put where its
    true reflectors no longer match the prediction) comes back this way; a lone wrong label does not.

    position (reflector, 3), seen and kept (reflector,) bool -> (reflector,) bool
    """
    left = np.flatnonzero(seen & ~kept)
    if tolerance_m <= 0 or len(left) < 2:
        return kept
    lo, hi = (b[np.ix_(left, left)] for b in bounds)
    _, limb = connected_components(np.isfinite(lo), directed=False)  # (left,) limb of each left-out reflector
    agree = within_bounds(position[left], lo, hi, tolerance_m)  # (left, left)
    copies = (np.linalg.norm(position[left][:, None] - position[kept][None], axis=-1) < coincide_m).any(1)
    kept = kept.copy()
    for g in np.unique(limb):
        members = limb == g
        if members.sum() >= 2 and agree[np.ix_(members, members)].all() and not copies[members].any():
            kept[left[members]] = True
    return kept


def predict(last: np.ndarray, before: np.ndarray | None, offsets: np.ndarray, bones: np.ndarray,
            reflector_offsets: np.ndarray) -> np.ndarray:
    """Where the reflectors should be in the next frame: where the last solved frame puts them plus their last
    step (constant velocity), extrapolated in space, not in the parameters, whose limb twists may trade off
    between frames.  last and before (40,) -> (reflector, 3)"""
    rot, pos = forward_kinematics(np.stack([last] if before is None else [last, before]), offsets)
    placed = reflector_positions(rot, pos, bones, reflector_offsets)  # (1 or 2, reflector, 3)
    return placed[0] if before is None else 2 * placed[0] - placed[1]


def gate(position: np.ndarray, seen: np.ndarray, expected: np.ndarray, *, gate_m: float, margin_m: float,
         min_reflectors: int) -> np.ndarray:
    """``seen`` less the reflectors whose measurement lies farther than ``gate_m`` from their prediction
    ``expected``, or more than ``margin_m`` nearer another reflector's prediction than their own (a label on a
    neighbouring strap, or on the other limb's); unchanged where that would leave fewer than ``min_reflectors``.

    position and expected (reflector, 3), seen (reflector,) bool -> (reflector,) bool
    """
    distance = np.linalg.norm(position[:, None] - expected[None], axis=-1)  # (measured, predicted), NaN rows unseen
    own = np.diagonal(distance)  # (reflector,)
    kept = seen.copy()
    if gate_m > 0:
        kept &= own <= gate_m
    if margin_m > 0:
        other = np.where(np.eye(len(own), dtype=bool), np.inf, distance).min(axis=1)  # nearest other prediction
        kept &= ~(own - other > margin_m)
    return kept if kept.sum() >= min_reflectors else seen


def from_views(observed: np.ndarray, weight: np.ndarray, kept: np.ndarray, expected: np.ndarray, estimates: np.ndarray,
               estimate_confidence: np.ndarray, *, view_m: float, margin_m: float,
               min_confidence: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The frame's measurements with, for each reflector without a kept one, the single view's estimate (under
    any label) nearest its prediction, within ``view_m`` and not ``margin_m`` nearer another reflector's
    prediction; each estimate serves one reflector, at its view's confidence. Fusion outvotes a view that
    labels a limb right when the other views swap the legs; its estimate still lies where the solve
    expects that reflector.

    observed and expected (reflector, 3), weight (reflector,), kept (reflector,) bool, estimates (n, 3) NaN where
    none, estimate_confidence (n,) -> observed, weight, kept with the estimates taken
    """
    valid = np.isfinite(estimates).all(1)
    if view_m <= 0 or not valid.any() or kept.all():
        return observed, weight, kept
    observed, weight, kept = observed.copy(), weight.copy(), kept.copy()
    estimates, estimate_confidence = estimates[valid], estimate_confidence[valid]
    distance = np.linalg.norm(estimates[:, None] - expected[None], axis=-1)  # (estimate, reflector)
    free = np.ones(len(estimates), bool)
    for r in np.flatnonzero(~kept):
        own = distance[:, r]
        other = np.delete(distance, r, axis=1).min(axis=1)
        ok = free & (own <= view_m) & ~(own - other > margin_m)
        if ok.any():
            k = np.flatnonzero(ok)[np.argmin(own[ok])]
            observed[r], weight[r], kept[r] = estimates[k], max(estimate_confidence[k], min_confidence), True
            free[k] = False
    return observed, weight, kept


def solve_sequence(position: np.ndarray, confidence: np.ndarray, offsets: np.ndarray, bones: np.ndarray,
                   reflector_offsets: np.ndarray, config: PoseConfig, *, estimates: np.ndarray | None = None,
                   estimate_confidence: np.ndarray | None = None,
                   initial: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Parameters of every frame: from the anchor frame forward, then from it backward, each frame warm-started
    from the one solved before it, or from its own ``initial`` parameters where given.

    position (frame, reflector, 3) NaN where missing, confidence (frame, reflector); optional single views'
    estimates (frame, n, 3) and their confidences (frame, n) for ``from_views``; optional ``initial`` (frame, 40),
    NaN where none: a previous solve of the same frames on a slightly different skeleton (the calibration's
    solves), which starts (and, by ``temporal_weight``, holds) each frame nearer its answer than another frame does
    -> params (frame, 40) NaN where unsolved, rms error (frame,), reflectors used (frame,)
    """
    n, min_confidence, min_reflectors = position.shape[0], config.min_confidence, config.min_reflectors
    max_iterations, tolerance, margin_m = config.max_iterations, config.tolerance, config.margin_m
    params, rms, used = np.full((n, N_DOF), np.nan), np.full(n, np.nan), np.zeros(n, np.int16)
    rest_weights = np.where(DISTAL, config.distal_rest_weight, config.rest_weight)
    seen_all = np.isfinite(position).all(2) & (np.nan_to_num(confidence) >= min_confidence)  # (frame, reflector)
    bounds = distance_bounds(offsets, bones, reflector_offsets)
    anchor = anchor_frame(position, seen_all, bounds, tolerance_m=config.rigid_tolerance_m, min_reflectors=min_reflectors)
    last = before = None  # the two frames solved last, in solving order
    for i in [*range(anchor, n), *range(anchor - 1, -1, -1)]:
        if i == anchor - 1:  # turn back: continue from the anchor's side (an anchor after frame 0 is always solved)
            last, before = params[anchor], _solved(params, anchor + 1)
        seen, observed, weight = seen_all[i], position[i], confidence[i]
        if seen.sum() < min_reflectors:
            continue
        if last is not None:
            expected = predict(last, before, offsets, bones, reflector_offsets)
            kept = gate(observed, seen, expected, gate_m=config.gate_m, margin_m=margin_m, min_reflectors=min_reflectors)
            seen = take_back(observed, seen, kept, bounds, tolerance_m=config.rigid_tolerance_m, coincide_m=margin_m)
            if estimates is not None:
                observed, weight, seen = from_views(observed, weight, seen, expected, estimates[i],
                                                    estimate_confidence[i], view_m=config.view_m, margin_m=margin_m,
                                                    min_confidence=min_confidence)
        used[i] = seen.sum()
        frame = (observed[seen], np.sqrt(np.clip(weight[seen], 0.0, 1.0)))
        rig = (offsets, bones[seen], reflector_offsets[seen])
        start = initial[i] if initial is not None and np.isfinite(initial[i]).all() else last
        if start is None:  # first frame: from the rest pose, held near it first to avoid twisted minima
            start = initial_params(np.where(seen[:, None], observed, np.nan), offsets, bones, reflector_offsets)
            start, _ = solve_frame(*frame, start, *rig, temporal_weight=0.0, rest_weights=10 * rest_weights,
                                   max_iterations=4 * max_iterations, tolerance=tolerance)
        params[i], rms[i] = solve_frame(*frame, start, *rig, temporal_weight=config.temporal_weight,
                                        rest_weights=rest_weights, max_iterations=max_iterations, tolerance=tolerance)
        last, before = params[i], last
    return params, rms, used


def _solved(params: np.ndarray, i: int) -> np.ndarray | None:
    """Frame i's parameters where it exists and was solved.  (frame, 40) -> (40,) or None"""
    return params[i] if 0 <= i < len(params) and np.isfinite(params[i]).all() else None


def solve_poses(skeleton: xr.Dataset, markers: xr.Dataset, views: xr.Dataset, config: PoseConfig) -> xr.Dataset:
    """`poses` stage: joint world positions and local rotations of every frame of a sequence, from the
    (smoothed) ``markers`` and, for reflectors they leave without data, the single views' estimates of ``views``
    (the fused markers' ``view_position`` and ``view_confidence``)."""
    names = [str(n) for n in markers["reflector"].values]
    skel = skeleton.sel(reflector=names)
    own = views.sel(reflector=names, frame=markers["frame"].values)
    n_frames = markers.sizes["frame"]
    estimates = own["view_position"].transpose("frame", "reflector", "view", "xyz").values.reshape(n_frames, -1, 3)
    estimate_confidence = own["view_confidence"].transpose("frame", "reflector", "view").values.reshape(n_frames, -1)
    offsets = skel["offset"].values.astype(np.float64)
    params, rms, used = solve_sequence(
        markers["position"].values.astype(np.float64), markers["confidence"].values.astype(np.float64), offsets,
        skel["bone"].values.astype(int), skel["reflector_offset"].values.astype(np.float64), config,
        estimates=estimates.astype(np.float64),
        estimate_confidence=estimate_confidence.astype(np.float64))
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

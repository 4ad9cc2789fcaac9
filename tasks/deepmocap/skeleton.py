"""Template skeleton calibration (DeepMoCap §3.5, Figure 9a, Eq. 11).

The template is the 20-joint, 40-DoF body of Figure 9a with hierarchy levels L0-L6 (the studio's
body at 1.75 m) and the rest position of every reflector on its bone. Each joint j has a reflector
subset RS_j (``REFLECTOR_SUBSETS``). Sides are anatomical everywhere: a reflector named ``L_...``
sits on the subject's left and a left joint's subset holds left reflectors. (The paper's Table
lists "Left Shoulder {R9, R10}", which are B_R_SHOULDER and F_R_SHOULDER in the released code's
channel order; we follow the anatomy, not that table.)

Calibration of one sequence:
1. coarse scaling: the median ratio of observed to template distances between the two straps of
   each forearm and shin, over the first batch of frames; then a fit of one scale per segment
   (trunk, shoulders, upper arm, forearm, hand, pelvis, thigh, shank, foot; left and right alike)
   that carries the template's reflectors onto the calibration frames, alternating with the pose
   solve (``fit_segment_scales``). The four strap distances alone are off by the straps' placement,
   several percent of a limb; the fit weighs every reflector of every calibration frame;
2. per hierarchy level L1-L6, G particles around each joint's current position in its parent's
   frame, moved with the optical data by forward kinematics of the poses solved on the current
   skeleton; Eq. (11): keep the particle whose distances to the high-confidence (C > 0.6)
   reflectors of RS_j and of the joint's own bone vary least over the frames (it moves most
   rigidly with them), with a weak pull to the template where the data cannot tell (a joint that
   never bends);
3. each reflector's offset in its bone frame: the median over frames of its observed position in
   the solved bone frame. Steps 2-3 alternate ``iterations`` times.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np
import xarray as xr
from scipy import sparse
from scipy.optimize import least_squares

from mocapflow.tasks.deepmocap.poses import PoseConfig, forward_kinematics, rest_pose_reflectors, solve_sequence
from mocapflow.tasks.shared.body import JOINT_NAMES, LEVELS, PARENTS, Subject, rest_offsets, surface
from mocapflow.tasks.shared.reflectors import place

TEMPLATE_HEIGHT = 1.75  # metres


REFLECTOR_SUBSETS: dict[str, tuple[str, ...]] = {
    "Hips": ("F_SPINEMID", "B_SPINEMID", "R_PELVIS", "L_PELVIS"),
    "SpineBase": ("F_SPINEMID", "B_SPINEMID"),
    "Neck": ("F_R_CHEST", "F_L_CHEST", "B_BACK"),
    "Head": ("F_R_HEAD", "F_L_HEAD", "B_HEAD"),
}
for _joint, _subset in {"Shoulder": ("F_x_SHOULDER", "B_x_SHOULDER"), "Elbow": ("x_ELBOW",), "Wrist": ("x_WRIST",),
                        "Hand": ("x_HAND",), "Hip": ("x_PELVIS",), "Knee": ("x_CALF",), "Ankle": ("x_ANKLE",),
                        "Foot": ("x_FOOT",)}.items():
    for _side in ("Left", "Right"):
        REFLECTOR_SUBSETS[_side + _joint] = tuple(n.replace("x", _side[0]) for n in _subset)  # anatomical side
assert set(REFLECTOR_SUBSETS) == set(JOINT_NAMES)

# Segments whose length scales together (left and right alike). A reflector scales with the segment
# its bone leads to: the forearm straps with the forearm, the pelvis patches with the pelvis, the
# shoulder patches with the shoulders; the head patches (an end bone) with the trunk.
SEGMENTS: dict[str, str] = {"Hips": "trunk", "SpineBase": "trunk", "Neck": "trunk", "Head": "trunk",
                            "Shoulder": "shoulders", "Elbow": "upper_arm", "Wrist": "forearm", "Hand": "hand",
                            "Hip": "pelvis", "Knee": "thigh", "Ankle": "shank", "Foot": "foot"}
_CARRIED_BY = {"Hips": "pelvis", "Neck": "shoulders", "Head": "trunk"}  # bones with several (or no) child segments

# The calibration's own pose solves: only confident data and more evaluations than the `poses` stage, since
# every solve moves the skeleton that the next one starts from (each from the last one's answer, so it
# converges in a few). Its frames are a selection, not consecutive, so there is no motion to gate by and no
# anchor to pick: in frame order. A stop at 1e-6 instead of 1e-4 took 28 % longer for the same skeleton.
CALIBRATION_SOLVE = PoseConfig(min_confidence=0.5, temporal_weight=0.01, rest_weight=0.002, distal_rest_weight=0.02,
                               max_iterations=50, min_reflectors=4, tolerance=1e-4, gate_m=0.0,
                               rigid_tolerance_m=0.0, margin_m=0.0, view_m=0.0)

# straps on one limb segment: their distance depends on the limb's length only (patches sit on the
# surface, so their distances also follow girth and placement, which vary far more between subjects)
_SCALE_PAIRS = (("R_ELBOW", "R_WRIST"), ("L_ELBOW", "L_WRIST"), ("R_CALF", "R_ANKLE"), ("L_CALF", "L_ANKLE"))


@dataclass(frozen=True)
class Template:
    offsets: np.ndarray  # (joint, 3) rest offset from the parent, metres
    bones: np.ndarray  # (reflector,) joint whose frame carries the reflector
    reflector_offsets: np.ndarray  # (reflector, 3) position in that joint's frame, metres


@dataclass(frozen=True)
class SkeletonConfig:
    batch_frames: int = 30  # frames of the coarse scaling
    frames: int = 60  # frames (evenly spread over the sequence) used by the particle calibration
    particles: int = 500  # G, per joint and round
    spread_m: float = 0.04  # particle spread (std) in the first round; halved each further round
    rounds: int = 2  # particle rounds per joint, each around the previous best
    min_confidence: float = 0.6  # C threshold of the data used to calibrate
    prior_weight: float = 0.05  # m^2 of Eq. (11) cost per m^2 of distance from the template
    outlier_m: float = 0.03  # largest distance change one frame may add to the Eq. (11) spread (robust cost)
    iterations: int = 2  # alternations of joint (step 2) and reflector-offset (step 3) estimation
    scale_rounds: int = 3  # alternations of pose solve and segment-scale fit after the coarse scaling (0: coarse only)
    scale_prior_m: float = 3.0  # metres of reflector error per unit of a segment's scale away from the common scale
    seed: int = 0

    def __post_init__(self):
        if not self.outlier_m > 0:
            raise ValueError(f"outlier_m must be > 0 metres (e.g. 0.03), got {self.outlier_m}")
        if self.scale_rounds < 0:
            raise ValueError(f"scale_rounds must be >= 0 (0 keeps the coarse scale), got {self.scale_rounds}")
        if not self.scale_prior_m > 0:
            raise ValueError(f"scale_prior_m must be > 0 metres (e.g. 3.0), got {self.scale_prior_m}")


def template(names: list[str]) -> Template:
    """The template body at 1.75 m and the rest position of each named reflector on its bone."""
    prims = surface(Subject(height=TEMPLATE_HEIGHT))
    placements = {p.name: p for p in place(prims)}
    unknown = sorted(set(names) - set(placements))
    if unknown:
        raise ValueError(f"reflectors {unknown} are not on the template; expected names from {sorted(placements)}")
    bones = np.array([prims[placements[n].prim].joint for n in names])
    return Template(rest_offsets(Subject(height=TEMPLATE_HEIGHT)), bones,
                    np.stack([placements[n].centre for n in names]))


def patch_normals(names: list[str]) -> np.ndarray:
    """Outward surface normal of each named patch in its bone's frame (the template's placement); zero for a
    strap, which is seen from every side.  -> (reflector, 3)"""
    placements = {p.name: p for p in place(surface(Subject(height=TEMPLATE_HEIGHT)))}
    unknown = sorted(set(names) - set(placements))
    if unknown:
        raise ValueError(f"reflectors {unknown} are not on the template; expected names from {sorted(placements)}")
    return np.stack([placements[n].normal if placements[n].kind == "patch" else np.zeros(3) for n in names])


def rest_reflector_positions(names: list[str]) -> np.ndarray:
    """World positions of the named reflectors on the template body in its rest pose.  -> (reflector, 3) m"""
    tmpl = template(names)
    return rest_pose_reflectors(tmpl.offsets, tmpl.bones, tmpl.reflector_offsets)


def neighbours(names: list[str], within_m: float) -> np.ndarray | None:
    """Which reflectors lie within ``within_m`` of each other on the rest-pose template (the two forehead
    patches, the chest patches): those that can share one image region or one point. None (any) when
    ``within_m`` is 0.  -> (R, R) bool"""
    return _neighbours(tuple(names), float(within_m))


@functools.lru_cache(maxsize=8)
def _neighbours(names: tuple[str, ...], within_m: float) -> np.ndarray | None:
    if within_m <= 0:
        return None
    rest = rest_reflector_positions(list(names))  # (R, 3), the template body built once per reflector set
    table = np.linalg.norm(rest[:, None] - rest[None], axis=-1) <= within_m
    table.flags.writeable = False  # shared between calls
    return table


def coarse_scale(position: np.ndarray, names: list[str], tmpl: Template) -> np.ndarray:
    """Subject size over template size, per joint: the median ratio of observed to template distances
    between the two straps of each forearm and shin.  position (frame, reflector, 3) -> (joint,)"""
    index = {n: i for i, n in enumerate(names)}
    refl = tmpl.reflector_offsets  # both straps of a pair ride on one bone: their offsets share a frame
    ratios = [np.linalg.norm(position[:, index[a]] - position[:, index[b]], axis=1)
              / np.linalg.norm(refl[index[a]] - refl[index[b]]) for a, b in _SCALE_PAIRS if a in index and b in index]
    ratios = np.concatenate(ratios) if ratios else np.array([])
    ratios = ratios[np.isfinite(ratios)]
    return np.full(len(JOINT_NAMES), float(np.median(ratios)) if ratios.size else 1.0)  # nothing seen: the template


def segment_groups(bones: np.ndarray) -> tuple[np.ndarray, np.ndarray, list[str]]:
    """Segment index of every joint's offset and of every reflector's offset (by its bone), and the
    segment names.  bones (reflector,) -> (joint,), (reflector,), names"""
    names = sorted(set(SEGMENTS.values()))
    kind = [n.removeprefix("Left").removeprefix("Right") for n in JOINT_NAMES]
    joint_group = np.array([names.index(SEGMENTS[k]) for k in kind])
    children = np.bincount(PARENTS[PARENTS >= 0], minlength=len(PARENTS))
    child = {p: j for j, p in enumerate(PARENTS) if p >= 0 and children[p] == 1}
    bone_group = np.array([names.index(_CARRIED_BY[kind[j]]) if kind[j] in _CARRIED_BY else joint_group[child.get(j, j)]
                           for j in range(len(JOINT_NAMES))])
    return joint_group, bone_group[bones], names


def _scale_design(rot: np.ndarray, tmpl: Template, joint_group: np.ndarray, refl_group: np.ndarray,
                  n_groups: int) -> np.ndarray:
    """Each reflector's position relative to the root as a linear function of the segment scales, the
    poses' rotations held: Σ_j s_g(j) R_parent(j) o_j + s_g(r) R_bone(r) c_r over the joints j from the
    root down to the reflector's bone.  rot (frame, joint, 3, 3) -> (frame, reflector, 3, group)"""
    design = np.zeros((len(rot), len(tmpl.bones), 3, n_groups))
    for r, bone in enumerate(tmpl.bones):
        design[:, r, :, refl_group[r]] += rot[:, bone] @ tmpl.reflector_offsets[r]
        j = bone
        while PARENTS[j] >= 0:  # the root's offset is its translation, a free parameter per frame
            design[:, r, :, joint_group[j]] += rot[:, PARENTS[j]] @ tmpl.offsets[j]
            j = PARENTS[j]
    return design


def _robust_linear(a: np.ndarray, b: np.ndarray, x0: np.ndarray, f_scale: float) -> np.ndarray:
    """argmin_x Σ soft_l1(a x - b) at ``f_scale``.  (m, n), (m,), (n,) -> (n,)

    ``a`` is mostly zeros (each frame's root columns touch that frame's rows only): sparse, with an iterative
    trust-region step at tolerances tight enough to land where the dense exact step does, fifty times faster.
    """
    design = sparse.csr_matrix(a)
    return least_squares(lambda x: design @ x - b, x0, jac=lambda x: design, loss="soft_l1", f_scale=f_scale,
                         tr_solver="lsmr", tr_options={"atol": 1e-12, "btol": 1e-12}).x


def fit_segment_scales(obs: np.ndarray, tmpl: Template, scale: np.ndarray, *, rounds: int, prior_m: float,
                       outlier_m: float) -> tuple[np.ndarray, np.ndarray]:
    """Per-segment scales of the template that best carry its reflectors onto the optical data.

    Alternates a pose solve on the current scales with a linear fit of the scales and each frame's root
    position, the rotations held: a reflector is x_fr = root_f + Σ_j s_g(j) R_parent(j) o_j + s_g(r) R_bone(r) c_r,
    linear in the segment scales s_g. Robust (soft L1 at ``outlier_m``), and each segment is pulled to a
    common scale with weight ``prior_m`` (metres of reflector error per unit of scale): the straps'
    placement along a limb varies by several percent of its length, so a segment measured by its own
    straps alone is that much off, while the common scale averages all of them; the pull also settles
    the segments no reflector measures (the hands' and feet's end joints).
    obs (frame, reflector, 3) NaN where unseen, scale (joint,) start -> per joint (joint,), per reflector (reflector,),
    the last round's poses (frame, 40) (None without rounds)
    """
    joint_group, refl_group, groups = segment_groups(tmpl.bones)
    n_g = len(groups)
    s = np.array([np.median(scale[joint_group == g]) for g in range(n_g)])
    seen = np.isfinite(obs).all(2)  # (frame, reflector)
    params = None
    for _ in range(rounds):
        params, _, _ = solve_sequence(obs, seen.astype(float), tmpl.offsets * s[joint_group][:, None], tmpl.bones,
                                      tmpl.reflector_offsets * s[refl_group][:, None], CALIBRATION_SOLVE,
                                      initial=params)  # each round starts from the last one's poses
        ok = np.isfinite(params).all(1)
        if ok.sum() < 3:
            break
        rot, _ = forward_kinematics(params[ok], tmpl.offsets)  # rotations do not depend on the offsets
        frame_of, refl_of = np.nonzero(seen[ok])  # one 3-row block per seen reflector
        n_f, m = int(ok.sum()), len(frame_of)
        a = np.zeros((m, 3, n_g + 1 + 3 * n_f))  # columns: s_g, the common scale, root_f
        a[..., :n_g] = _scale_design(rot, tmpl, joint_group, refl_group, n_g)[frame_of, refl_of]
        for k in range(3):
            a[np.arange(m), k, n_g + 1 + 3 * frame_of + k] = 1.0
        prior = np.zeros((n_g, a.shape[-1]))
        prior[np.arange(n_g), np.arange(n_g)], prior[:, n_g] = prior_m, -prior_m  # w (s_g - c)
        x0 = np.concatenate([s, [np.median(s)], params[ok][:, :3].reshape(-1)])
        x = _robust_linear(np.vstack([a.reshape(3 * m, -1), prior]),
                           np.concatenate([obs[ok][seen[ok]].reshape(-1), np.zeros(n_g)]), x0, outlier_m)
        s = np.clip(x[:n_g], 0.7 * np.median(s), 1.3 * np.median(s))  # a degenerate fit cannot run off
    return s[joint_group], s[refl_group], params


def calibration_frames(position: np.ndarray, confidence: np.ndarray, *, frames: int, min_confidence: float) -> np.ndarray:
    """Indices of up to ``frames`` well-observed frames spread over the sequence.  (frame, reflector, 3) -> (k,)"""
    good = np.isfinite(position).all(2) & (np.nan_to_num(confidence) > min_confidence)
    candidates = np.flatnonzero(good.sum(1) >= max(4, 0.5 * position.shape[1]))
    if candidates.size == 0:
        return candidates
    take = np.unique(np.linspace(0, candidates.size - 1, min(frames, candidates.size)).round().astype(int))
    return np.sort(candidates[take])


def rigidity_cost(particles_world: np.ndarray, targets: np.ndarray, *, outlier_m: float) -> np.ndarray:
    """Eq. (11), made robust: summed spread over frames of each particle's distance to each target.

    The spread is taken about the median distance, and one frame adds at most ``outlier_m``²: a few frames
    of wrong optical data (a mislabelled or drifted reflector) cannot outweigh the rest, as they do the
    plain variance. particles_world (frame, particle, 3), targets (frame, target, 3) NaN where unseen -> (particle,)
    """
    d = np.linalg.norm(particles_world[:, :, None] - targets[:, None], axis=-1)  # (frame, particle, target)
    seen = np.isfinite(d)
    n = seen.sum(0)
    centre = np.zeros(d.shape[1:])
    some = n > 0
    centre[some] = _nanmedian_first(d[:, some], n[some])
    spread = np.where(seen, np.minimum((d - centre) ** 2, outlier_m**2), 0.0).sum(0) / np.maximum(n - 1, 1)  # Eq. (11)
    return np.where(n >= 3, spread, 0.0).sum(1)


def _nanmedian_first(values: np.ndarray, count: np.ndarray) -> np.ndarray:
    """``np.nanmedian(values, axis=0)``, the same bits, from one sort: the mean of the middle two of the ``count``
    (> 0) finite values of each column (the middle one twice when odd), as numpy's masked median takes it.
    (frame, ...) with NaN, (...) -> (...)"""
    ordered = np.sort(values, axis=0)  # NaN last
    high = (count // 2)[None]
    low = np.where(count % 2 == 1, high[0], high[0] - 1)[None]
    return (np.take_along_axis(ordered, low, axis=0)[0] + np.take_along_axis(ordered, high, axis=0)[0]) / 2.0


def best_particle(parent_rot: np.ndarray, parent_pos: np.ndarray, targets: np.ndarray, current: np.ndarray,
                  prior: np.ndarray, config: SkeletonConfig, rng: np.random.Generator) -> np.ndarray:
    """The joint offset (in its parent's frame) that moves most rigidly with ``targets``: ``config.rounds`` rounds
    of ``config.particles`` particles, each round around the last one's best.

    parent_rot (frame, 3, 3), parent_pos (frame, 3), targets (frame, target, 3), current/prior (3,) -> (3,)
    """
    best = current
    for k in range(config.rounds):
        cloud = best + rng.normal(0.0, config.spread_m / 2**k, (config.particles, 3))
        cloud[0] = best
        world = np.einsum("fij,pj->fpi", parent_rot, cloud) + parent_pos[:, None]  # (frame, particle, 3)
        cost = (rigidity_cost(world, targets, outlier_m=config.outlier_m)
                + config.prior_weight * np.sum((cloud - prior) ** 2, axis=1))
        best = cloud[np.argmin(cost)]
    return best


def reflector_offsets(position: np.ndarray, rot: np.ndarray, pos: np.ndarray, bones: np.ndarray,
                      fallback: np.ndarray) -> np.ndarray:
    """Median position of each reflector in its bone frame.  (frame, reflector, 3), (frame, joint, 3, 3) -> (reflector, 3)"""
    local = np.einsum("frji,frj->fri", rot[:, bones], position - pos[:, bones])  # R^T (x - p)
    seen = np.isfinite(local[..., 0]).any(axis=0)  # (reflector,)
    out = fallback.copy()
    out[seen] = np.nanmedian(local[:, seen], axis=0)
    return out


def calibrate(position: np.ndarray, confidence: np.ndarray, names: list[str],
              config: SkeletonConfig) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, int]:
    """Joint offsets, reflector bones and offsets, and the template scale of one sequence's optical data.

    position (frame, reflector, 3) NaN where missing, confidence (frame, reflector)
    -> offsets (joint, 3), bones (reflector,), reflector offsets (reflector, 3), template scale per joint (joint,),
       frames used (0: too few well-observed frames, the scaled template is returned)
    """
    tmpl = template(names)
    scale = coarse_scale(position[:config.batch_frames], names, tmpl)
    sel = calibration_frames(position, confidence, frames=config.frames, min_confidence=config.min_confidence)
    obs = np.where((np.nan_to_num(confidence[sel]) > config.min_confidence)[..., None], position[sel], np.nan)
    conf = np.where(np.isfinite(obs[..., 0]), 1.0, 0.0)
    solve = CALIBRATION_SOLVE
    refl_scale, params = scale[tmpl.bones], None
    if sel.size >= 3 and config.scale_rounds:
        scale, refl_scale, params = fit_segment_scales(obs, tmpl, scale, rounds=config.scale_rounds,
                                                       prior_m=config.scale_prior_m, outlier_m=config.outlier_m)
    offsets, refl = tmpl.offsets * scale[:, None], tmpl.reflector_offsets * refl_scale[:, None]
    prior = offsets.copy()
    if sel.size < 3:
        return offsets, tmpl.bones, refl, scale, 0
    rng = np.random.default_rng(config.seed)  # each solve below starts from the last one's poses: the skeleton changes little
    for _ in range(config.iterations):
        for level in range(1, LEVELS.max() + 1):
            params, _, _ = solve_sequence(obs, conf, offsets, tmpl.bones, refl, solve, initial=params)
            ok = np.isfinite(params).all(1)
            rot, pos = forward_kinematics(params[ok], offsets)
            for j in np.flatnonzero(LEVELS == level):
                own = [r for r, b in enumerate(tmpl.bones) if b == j]
                targets = sorted({names.index(n) for n in REFLECTOR_SUBSETS[JOINT_NAMES[j]] if n in names} | set(own))
                offsets[j] = best_particle(rot[:, PARENTS[j]], pos[:, PARENTS[j]], obs[ok][:, targets], offsets[j],
                                           prior[j], config, rng)
        params, _, _ = solve_sequence(obs, conf, offsets, tmpl.bones, refl, solve, initial=params)
        ok = np.isfinite(params).all(1)
        rot, pos = forward_kinematics(params[ok], offsets)
        refl = reflector_offsets(obs[ok], rot, pos, tmpl.bones, refl)
    return offsets, tmpl.bones, refl, scale, int(sel.size)


def calibrate_skeleton(markers: xr.Dataset, config: SkeletonConfig) -> xr.Dataset:
    """`skeleton` stage: the calibrated template of one sequence from its 3D optical data."""
    names = [str(n) for n in markers["reflector"].values]
    offsets, bones, refl, scale, used = calibrate(markers["position"].values.astype(np.float64),
                                                  markers["confidence"].values.astype(np.float64), names, config)
    return xr.Dataset(
        {"offset": (("joint", "xyz"), offsets.astype(np.float32)),
         "bone_length": (("joint",), np.linalg.norm(offsets, axis=1).astype(np.float32)),
         "scale": (("joint",), scale.astype(np.float32)),
         "parent": (("joint",), PARENTS.astype(np.int16)),
         "level": (("joint",), LEVELS.astype(np.int8)),
         "bone": (("reflector",), bones.astype(np.int16)),
         "reflector_offset": (("reflector", "xyz"), refl.astype(np.float32))},
        coords={"joint": np.array(JOINT_NAMES, dtype=object), "reflector": np.array(names, dtype=object),
                "xyz": ["x", "y", "z"]},
        attrs={"length_unit": "m", "up_axis": "Z", "template_height_m": TEMPLATE_HEIGHT, "calibration_frames": used},
    )

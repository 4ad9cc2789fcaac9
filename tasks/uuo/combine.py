"""Three monocular priors of one take combined robustly into one (beyond Milef et al. 2024, §3.3).

UUO starts from one monocular body estimate per take (HMR 2.0 in the paper, §3.3). One estimate sometimes has a
limb flipped in depth for a while, or the whole body turned; part matching and the solver start from those
errors and do not always remove them. Three estimates of the same take (three draws of ``simulated_prior``, or
the monocular estimator run on its input perturbed: ``MonocularPriorConfig.shift_px``, ``scale``, ``flip``) are
combined here per frame and per bone, so that an error made by one draw only is outvoted:

1. alignment: draws 1 and 2 are brought onto draw 0 rigidly over the take, by one yaw about the vertical and one
   translation (the draws' unknown global yaw and position differ; part matching will later place the result
   with one rotation for the take and a translation per frame, §3.4.2). The yaw is fitted to the joints of the
   frames both draws kept, each frame centred (so a drifting position does not turn it), by a 2D Kabsch refitted
   on the ``align_keep`` share of the joints nearest after the previous fit (a flipped limb does not turn the
   body); the translation is the per-axis median over those frames of the joints' centroids' offsets;
2. rotations: each bone's rotation relative to its parent (the root's: its world rotation, after the alignment),
   per frame, the robust mean of the draws that kept the frame (``rotation``): ``cauchy`` (the default), the
   median below refined by a mean that weights each draw less the farther it lies (a Cauchy M-estimator, scale
   ``cauchy_deg``); ``median``, the chordal L1 median of the unit quaternions (signs aligned to the medoid's),
   found by Weiszfeld's iterations and normalised; ``medoid``, the draw closest to the others (summed geodesic
   angle); ``mean``, the normalised chordal mean (not robust, for comparison). With two voters each is their mean
   (the medoid: one of them), with one that draw. Each joint's
   articulation is voted on its own, so a limb one draw flips (one bone's rotation, its children following) or a
   body one draw turns (the root's) is outvoted without moving the bones below it;
3. root: the per-axis median of the aligned roots of the draws that kept the frame (two: their mean);
4. validity: a frame is valid where at least ``min_votes`` draws kept it; the others hold the nearest valid
   frame's combination (lost frames are held, as in prior.py);
5. shape: each phenotype parameter the median of the three draws'; the 20 joints are posed anew from the
   combined rotations, root and shape.

Which rotation average (``python benchmarks/uuo_prior_calibration.py --draws 3 --seeds 3``: the 30 procedural
takes of 90 frames, three independent realistic draws each, the error after part matching's alignment, median /
p90 over takes): the take's median draw alone 153.2 / 180.9 mm; combined by ``cauchy`` **85.7 / 108.9 mm**,
``median`` 91.2 / 114.3, ``mean`` 95.3 / 116.2, ``medoid`` 111.9 / 139.3. With the flips made larger (90-150
degrees, ``--set flip_deg=90,150``; one draw 246.2 / 290.5 mm): ``cauchy`` 131.7 / 173.9, ``median`` 141.1 /
185.2, ``medoid`` 156.8 / 202.9, ``mean`` 188.8 / 242.7. The medoid keeps one draw's own error; the mean follows an
outlier a third of the way; the median bounds an outlier's pull but averages agreeing draws less well than a mean.
``cauchy`` starts from the median and then weights each draw by 1 / (1 + (d / c)^2), d its chord from the estimate
and c the chord of ``cauchy_deg`` (30; 10-60 measured, 20-40 within 3 mm of the best): draws that agree average
like a mean, a far one counts little (a 140-degree flip against two agreeing draws pulls the result about 3
degrees; tests/tasks/uuo/test_combine.py). Voting each joint's rotation relative to its parent beat voting world
rotations (91.2 against 94.2 mm median with ``median``; better on 24 of the 30 takes). The simulated draws' errors
are independent of each other; a real estimator's reruns (its input perturbed) err in correlated ways, so three
of them gain less: BlazePose on the studio's video as filmed, moved 12 px and mirrored (``--form monocular``, 20
takes) is at 127.4 / 161.6 mm from one run and 123.6 / 147.2 mm combined (``cauchy``), its runs 3.7 degrees apart
(``spread_deg``, median) where the simulated draws are 11.9.

The result records how far the draws were apart and how they were aligned (attrs): ``spread_deg`` and
``spread_p90_deg`` (the angle between two draws' rotations of one articulated bone relative to its parent, the
SMPL-like bones of prior.PRIOR_BONES, over every voting pair, frame and bone), ``draw_deviation_deg`` (each draw's
median angle from the combination on those bones), ``draw_outvoted`` (each draw's share of its voted frame-bones
more than ``far_deg`` from the combination), ``aligned_yaw_deg`` and
``aligned_translation_m`` (what was applied to each draw; draw 0 is the reference), ``alignment_gap_mm`` (each
draw's median joint distance to draw 0 after it), ``vote_frames`` (frames kept by 0, 1, 2 and 3 draws) and the
draws' ``sources``. It does not carry the draws' own error figures (``aligned_mpjpe_mm``, ...): those describe one
draw, not the combination.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import xarray as xr
from scipy.spatial.transform import Rotation

from mocapflow.tasks.shared.kinematics import forward_kinematics, local_rotations, world_rotations
from mocapflow.tasks.shared.mesh_body import Phenotype, mesh_body
from mocapflow.tasks.uuo.matching import yaw_matrix
from mocapflow.tasks.uuo.prior import PRIOR_BONES, PriorError, nearest_kept, prior_dataset

ROTATION_AVERAGES = ("cauchy", "median", "medoid", "mean")
_QUAT = ["x", "y", "z", "w"]


class CombineError(PriorError):
    """Priors that cannot be combined (not of one take, one rig, one shape's parameters) or settings out of range."""


@dataclass(frozen=True)
class CombinePriorsConfig:
    """How three body priors of one take are combined (the module's docstring)."""

    rotation: str = "cauchy"  # cauchy | median (chordal L1, Weiszfeld) | medoid (the draw closest to the others) | mean
    cauchy_deg: float = 30.0  # cauchy: draws this far apart still average; farther ones count less and less
    iterations: int = 30  # iterations of the median (Weiszfeld) and then of the Cauchy-weighted mean
    align: bool = True  # draws 1 and 2 turned (yaw) and moved onto draw 0 first; off for draws sharing one frame
    align_keep: float = 0.8  # the yaw is refitted on this share of the joints nearest after the previous fit
    min_votes: int = 2  # a frame is valid where at least this many draws kept it
    far_deg: float = 30.0  # a draw this far from the combination on a frame-bone was outvoted (attrs draw_outvoted)

    def __post_init__(self):
        if self.rotation not in ROTATION_AVERAGES:
            raise CombineError(f"combine rotation {self.rotation!r} is unknown; use one of {list(ROTATION_AVERAGES)}")
        if self.iterations < 1 or not 0 < self.align_keep <= 1 or self.min_votes not in (1, 2, 3) \
                or not 0 < self.far_deg <= 180 or not 0 < self.cauchy_deg <= 180:
            raise CombineError(f"combine settings out of range: iterations >= 1 (got {self.iterations}), align_keep "
                               f"in (0, 1] (got {self.align_keep}), min_votes 1, 2 or 3 (got {self.min_votes}), "
                               f"far_deg and cauchy_deg in (0, 180] (got {self.far_deg}, {self.cauchy_deg})")


# ---- kernels -------------------------------------------------------------------------------------------------

def align_yaw(source: np.ndarray, target: np.ndarray, keep: float = 0.8, rounds: int = 3) -> tuple[float, np.ndarray]:
    """The yaw (radians, about z) and translation taking ``source``'s joints onto ``target``'s over a take: the yaw
    by a 2D Kabsch on each frame's centred joints, refitted ``rounds`` times on the ``keep`` share of the joints
    nearest after the last fit; the translation the per-axis median of the centroids' offsets.
    (frame, joint, 3) x 2 -> (theta, (3,))"""
    a = source - source.mean(axis=1, keepdims=True)
    b = target - target.mean(axis=1, keepdims=True)
    weight = np.ones(a.shape[:2])
    theta = 0.0
    for _ in range(rounds):
        cross = (weight * (a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0])).sum()
        dot = (weight * (a[..., 0] * b[..., 0] + a[..., 1] * b[..., 1])).sum()
        theta = float(np.arctan2(cross, dot))
        gap = np.linalg.norm(a @ yaw_matrix(theta).T - b, axis=-1)
        weight = (gap <= np.quantile(gap, keep)).astype(float)
    turn = yaw_matrix(theta)
    shift = np.median(target.mean(axis=1) - source.mean(axis=1) @ turn.T, axis=0)
    return theta, shift


def quat_angle(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Geodesic angle (radians) between unit quaternions (..., 4), either sign."""
    return 2.0 * np.arccos(np.clip(np.abs((p * q).sum(-1)), 0.0, 1.0))


def robust_rotation(quats: np.ndarray, votes: np.ndarray, method: str = "cauchy", iterations: int = 30,
                    cauchy_deg: float = 30.0) -> np.ndarray:
    """The robust mean of each (frame, bone)'s rotations over the draws that vote (module docstring, step 2).

    quats (draw, frame, bone, 4) unit quaternions x y z w; votes (draw, frame) bool, at least one per frame
    -> (frame, bone, 4) unit quaternions"""
    w = votes[:, :, None].astype(float)  # (draw, frame, 1)
    n = quats.shape[0]
    pair = np.stack([quat_angle(quats[i], quats[j]) for i in range(n) for j in range(n)]).reshape((n, n) + quats.shape[1:3])
    cost = (pair * w[None]).sum(axis=1)  # (draw, frame, bone): summed angle to the other voters
    cost = np.where(w > 0, cost, np.inf)
    medoid = np.take_along_axis(quats, cost.argmin(axis=0)[None, ..., None], axis=0)[0]  # (frame, bone, 4)
    if method == "medoid":
        return medoid
    signed = quats * np.where((quats * medoid[None]).sum(-1, keepdims=True) < 0, -1.0, 1.0)
    wq = w[..., None]
    x = (signed * wq).sum(0) / wq.sum(0)
    if method in ("median", "cauchy"):  # Weiszfeld: the point of least summed distance to the voters, in R^4
        for _ in range(iterations):
            weight = wq / np.maximum(np.linalg.norm(signed - x[None], axis=-1, keepdims=True), 1e-9)
            x = (signed * weight).sum(0) / weight.sum(0)
    if method == "cauchy":  # from the median, a mean weighted 1 / (1 + (d / c)^2): c the chord of cauchy_deg
        chord = 2.0 * np.sin(np.radians(cauchy_deg) / 4.0)
        for _ in range(iterations):
            weight = wq / (1.0 + (np.linalg.norm(signed - x[None], axis=-1, keepdims=True) / chord) ** 2)
            x = (signed * weight).sum(0) / weight.sum(0)
    return x / np.linalg.norm(x, axis=-1, keepdims=True)


# ---- the stage -----------------------------------------------------------------------------------------------

def _check(draws: tuple[xr.Dataset, ...]) -> None:
    """Three priors of one take: the same frames, bones, joints, phenotype parameters and frame rate."""
    first = draws[0]
    for k, d in enumerate(draws):
        missing = [v for v in ("bone_rotation", "root", "joints", "valid") if v not in d] + \
            [f"{a} attribute" for a in ("phenotype",) if a not in d.attrs]
        if missing:
            raise CombineError(f"prior {k} lacks {missing}; combine body_prior datasets (the output of a prior stage)")
        if "quat" in d.coords and [str(c) for c in d["quat"].values] != _QUAT:
            raise CombineError(f"prior {k}'s quaternions are ordered {list(d['quat'].values)}, not {_QUAT}; "
                               "write them x y z w as the prior stages do")
    for k, d in enumerate(draws[1:], start=1):
        f0, fk = first["frame"].values, d["frame"].values
        if len(fk) != len(f0) or not np.array_equal(fk, f0):
            bad = "their count" if len(fk) != len(f0) else f"frame {fk[np.flatnonzero(fk != f0)[0]]}"
            raise CombineError(f"prior {k} has {len(fk)} frames ({fk[:1].tolist()}..{fk[-1:].tolist()}) and prior 0 "
                               f"{len(f0)} ({f0[:1].tolist()}..{f0[-1:].tolist()}), differing in {bad}; make the "
                               "three priors from the same take (one markers stage)")
        for coord, what in (("bone", "bones"), ("joint", "joints")):
            b0, bk = [str(x) for x in first[coord].values], [str(x) for x in d[coord].values]
            if b0 != bk:
                diff = next((i for i, (x, y) in enumerate(zip(b0, bk)) if x != y), min(len(b0), len(bk)))
                got = bk[diff] if diff < len(bk) else "nothing"
                want = b0[diff] if diff < len(b0) else "nothing"
                raise CombineError(f"prior {k}'s {what} differ from prior 0's: at {diff} it has {got!r} where prior 0 "
                                   f"has {want!r} ({len(bk)} against {len(b0)}); combine priors of one body rig "
                                   "(Anny's bones, the template's 20 joints)")
        p0, pk = set(first.attrs["phenotype"]), set(d.attrs["phenotype"])
        if p0 != pk:
            raise CombineError(f"prior {k}'s phenotype has keys {sorted(pk)}, prior 0's {sorted(p0)} (missing "
                               f"{sorted(p0 - pk)}, extra {sorted(pk - p0)}); combine priors of Anny's phenotype")
        r0, rk = float(first.attrs.get("fps", 0.0)), float(d.attrs.get("fps", 0.0))
        if r0 > 0 and rk > 0 and abs(r0 - rk) > 1e-6:
            raise CombineError(f"prior {k} runs at {rk} frames/s and prior 0 at {r0}; make the three priors from the "
                               "same take")


def combine_priors(prior0: xr.Dataset, prior1: xr.Dataset, prior2: xr.Dataset,
                   config: CombinePriorsConfig) -> xr.Dataset:
    """Stage ``prior`` (combined): three body priors of one take combined per frame and bone (module docstring);
    the result is a body_prior."""
    draws = (prior0, prior1, prior2)
    _check(draws)
    quats = np.stack([d["bone_rotation"].transpose("frame", "bone", "quat").values.astype(np.float64) for d in draws])
    roots = np.stack([d["root"].transpose("frame", "xyz").values.astype(np.float64) for d in draws])
    joints = np.stack([d["joints"].transpose("frame", "joint", "xyz").values.astype(np.float64) for d in draws])
    votes = np.stack([d["valid"].values.astype(bool) for d in draws])
    n_draws, n, n_bones = quats.shape[:3]
    if not np.isfinite(quats).all() or not np.isfinite(roots).all():
        bad = [k for k in range(n_draws) if not (np.isfinite(quats[k]).all() and np.isfinite(roots[k]).all())]
        raise CombineError(f"prior(s) {bad} hold non-finite rotations or roots; a prior holds lost frames, it does "
                           "not leave them NaN (remake it with a prior stage)")
    count = votes.sum(axis=0)
    valid = count >= config.min_votes
    if not valid.any():
        raise CombineError(f"no frame of the take is kept by {config.min_votes} of the three priors (frames kept by "
                           f"each: {votes.sum(axis=1).tolist()} of {n}); combine priors that found the body, or "
                           "lower min_votes")

    yaws, shifts, gaps = [0.0], [np.zeros(3)], [0.0]
    for k in range(1, n_draws):
        both = votes[0] & votes[k]
        use = both if both.any() else np.ones(n, bool)
        theta, shift = align_yaw(joints[k, use], joints[0, use], config.align_keep) if config.align \
            else (0.0, np.zeros(3))
        turn = yaw_matrix(theta)
        turn_q = Rotation.from_matrix(turn)
        quats[k] = (turn_q * Rotation.from_quat(quats[k].reshape(-1, 4))).as_quat().reshape(n, n_bones, 4)
        roots[k] = roots[k] @ turn.T + shift
        joints[k] = joints[k] @ turn.T + shift
        yaws.append(float(np.degrees(theta)))
        shifts.append(shift)
        gaps.append(1000.0 * float(np.median(np.linalg.norm(joints[k, use] - joints[0, use], axis=-1))))

    phenotype = {key: float(np.median([d.attrs["phenotype"][key] for d in draws])) for key in prior0.attrs["phenotype"]}
    body = mesh_body(Phenotype(**phenotype))
    bones = [str(b) for b in prior0["bone"].values]
    if bones != list(body.bone_names):
        raise CombineError(f"the priors' {len(bones)} bones are not Anny's {len(body.bone_names)} (first {bones[:3]}); "
                           "combine priors made by the prior stages")
    parents = body.bone_parents
    local = np.stack([Rotation.from_matrix(local_rotations(
        Rotation.from_quat(q.reshape(-1, 4)).as_matrix().reshape(n, n_bones, 3, 3), parents).reshape(-1, 3, 3))
        .as_quat().reshape(n, n_bones, 4) for q in quats])  # (draw, frame, bone, 4), the root's its world rotation

    voters = np.where(count[None] > 0, votes, True)  # a frame nobody kept: all hold something, all vote (then held)
    combined = robust_rotation(local, voters, config.rotation, config.iterations, config.cauchy_deg)
    root = np.nanmedian(np.where(voters[..., None], roots, np.nan), axis=0)
    held = nearest_kept(valid)
    combined, root = combined[held], root[held]

    # how far apart the draws' articulations were, and how far each lay from the combination, on the frames it voted
    articulated = np.array([b in PRIOR_BONES for b in body.bone_names])

    def angle(p: np.ndarray, q: np.ndarray) -> np.ndarray:  # (frame, articulated bone) degrees
        return np.degrees(quat_angle(p[:, articulated], q[:, articulated]))

    pairs = [(i, j) for i in range(n_draws) for j in range(i + 1, n_draws)]
    spread = np.concatenate([angle(local[i], local[j])[votes[i] & votes[j]].ravel() for i, j in pairs])
    deviation = [angle(local[k], combined)[votes[k] & valid].ravel() for k in range(n_draws)]

    local_m = Rotation.from_quat(combined.reshape(-1, 4)).as_matrix().reshape(n, n_bones, 3, 3)
    world = world_rotations(local_m, parents)
    offsets = body.rest_heads - np.where(parents[:, None] >= 0, body.rest_heads[np.maximum(parents, 0)], 0.0)
    heads = forward_kinematics(local_m, root, offsets, parents)[1]

    def stat(values: np.ndarray, q: float) -> float:
        return float(np.percentile(values, q)) if len(values) else None

    fps = float(prior0.attrs.get("fps", 0.0))
    return prior_dataset(
        prior0["frame"].values, body, world, root, heads[:, body.joint_bones()], valid, fps, Phenotype(**phenotype),
        "combined", sources=[str(d.attrs.get("source", "")) for d in draws], rotation=config.rotation,
        spread_deg=stat(spread, 50), spread_p90_deg=stat(spread, 90),
        draw_deviation_deg=[stat(d, 50) for d in deviation],
        draw_outvoted=[float((d > config.far_deg).mean()) if len(d) else None for d in deviation],
        aligned_yaw_deg=yaws, aligned_translation_m=[[float(v) for v in s] for s in shifts],
        alignment_gap_mm=gaps, vote_frames=[int((count == c).sum()) for c in range(n_draws + 1)])

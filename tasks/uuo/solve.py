"""UUO's mocap solver as pipeline stages (Milef et al. 2024, §3.4-3.5), one per root-yaw hypothesis and one to
choose and refine.

``solve_hypothesis`` (a stage per hypothesis y of B = {0, 90, 180, 270} degrees, so each runs as its own task):
part matching (§3.4.2) from the yaw y, pose fitting (stage 2), marker-vertex correspondence (stage 3) and
inverse kinematics (stage 4); its result carries the one-directional chamfer distance of Eq. (3).
``best_hypothesis`` keeps the hypothesis of least chamfer (Eq. 3, stage 1); where others come close (within
``close`` times the least), the one whose pose agrees best with the prior's own joint rotations and whose rigid
groups keep to one side (a solve turned around or mirrored bends its limbs unlike the prior and splits groups
across sides); it refines it (stage 5: stages 3
and 4 again, anchored to stage 4's result); ``single_hypothesis`` is the same on one hypothesis (the paper's
"- MHT" ablation); ``rigid_prior`` is the baseline without a solve, the prior placed by part matching. Every
result is a body over the take (bone rotations, root, phenotype, joints) and a vertex and body part per marker
trajectory. Every solve keeps the skin above the floor (``floor_plane``; not in the paper).
"""

from __future__ import annotations

import dataclasses
import logging
from dataclasses import dataclass, field

import numpy as np
import xarray as xr
from scipy.spatial.transform import Rotation

from mocapflow.tasks.shared.body import JOINT_NAMES
from mocapflow.tasks.shared.cache import BoundedCache
from mocapflow.tasks.shared.mesh_body import PHENOTYPE_NAMES, MeshBody, Phenotype, mesh_body, part_of_bone, \
    part_sides
from mocapflow.tasks.shared.kinematics import local_rotations
from mocapflow.tasks.shared.solver_body import SolverBody
from mocapflow.tasks.uuo.correspondence import CorrespondenceConfig, correspond
from mocapflow.tasks.uuo.fitting import Floor, floor_vertices
from mocapflow.tasks.shared.solver_body import BodyFit, posed_heads, posed_vertices
from mocapflow.tasks.uuo import hypotheses as hyp
from mocapflow.tasks.uuo.hypotheses import ScreenConfig
from mocapflow.tasks.uuo.ik import IKConfig, inverse_kinematics
from mocapflow.tasks.uuo.matching import MatchConfig, closest, evenly, match_parts, mirror_parts, part_vertices, \
    search_parts, try_chain
from mocapflow.tasks.uuo.pose_fit import PoseFitConfig, fit_pose

logger = logging.getLogger(__name__)

STAGES = ("matching", "pose_fit", "ik", "refined")
_BODIES: BoundedCache[tuple, tuple] = BoundedCache(2)


class SolveError(ValueError):
    """Inputs the solver cannot use."""


@dataclass(frozen=True)
class HypothesisConfig:
    yaw_deg: float = 0.0  # the hypothesis' starting root yaw (§3.5.1)
    mirror: bool = False  # the prior mirrored left-right first (hypotheses.mirrored)
    matching: MatchConfig = field(default_factory=MatchConfig)
    pose_fit: PoseFitConfig = field(default_factory=PoseFitConfig)
    correspondence: CorrespondenceConfig = field(default_factory=CorrespondenceConfig)
    ik: IKConfig = field(default_factory=IKConfig)
    outlier_m: float = 0.1  # a sample's distance is capped here in the chamfer of Eq. (3), so ghosts do not choose
    floor: bool = True  # keep the skin above the floor plane (floor_plane)
    hinge_tolerance_deg: float = 10.0  # a knee or elbow bent this far against its hinge is still plausible


@dataclass(frozen=True)
class ScreenedConfig:
    rank: int = 0  # which of the screen's placements (0: the best) this stage solves
    solve: HypothesisConfig = field(default_factory=HypothesisConfig)

    def __post_init__(self):
        if self.rank < 0:
            raise SolveError(f"rank counts the screen's placements from 0 (the best), got {self.rank}")


@dataclass(frozen=True)
class RefineConfig:
    correspondence: CorrespondenceConfig = field(default_factory=CorrespondenceConfig)
    ik: IKConfig = field(default_factory=IKConfig)
    # The rule's settings were chosen on the tuning split by benchmarks/uuo_tune.py (docs/uuo.md, Tuning on record).
    close: float = 1.25  # hypotheses whose chamfer is within this factor of the least are close: among them ...
    split_deg: float = 100.0  # ... the least prior_pose_deg + split_deg * side_split ...
    hinge_weight: float = 2.0  # ... + hinge_weight * hyperextension_deg ...
    travel_deg: float = 0.0  # ... + travel_deg * backward_travel wins (not turned or mirrored)
    call_deg: float = 2.0  # a runner-up facing or sided otherwise within this of the winner's score: too close
    floor: bool = True  # keep the skin above the floor plane (floor_plane)

    def __post_init__(self):
        if self.close < 1.0 or min(self.split_deg, self.hinge_weight, self.travel_deg, self.call_deg) < 0:
            raise SolveError(f"refine needs close >= 1 and split_deg, hinge_weight, travel_deg, call_deg >= 0, got "
                             f"{self.close}, {self.split_deg}, {self.hinge_weight}, {self.travel_deg}, "
                             f"{self.call_deg}")


def robust_score(h: xr.Dataset, config: RefineConfig) -> float:
    """A close hypothesis' implausibility, in degrees: its pose against the prior's, its rigid groups split across
    the sides, its knees and elbows bent backward, its walk backward."""
    a = h.attrs
    return float(a["prior_pose_deg"] + config.split_deg * a["side_split"]
                 + config.hinge_weight * a.get("hyperextension_deg", 0.0)
                 + config.travel_deg * a.get("backward_travel", 0.0))


@dataclass(frozen=True)
class Choice:
    index: int  # the hypothesis kept
    runner_up: int | None  # the best close hypothesis facing more than 90 degrees away or mirrored, if any
    margin_deg: float  # its score less the winner's (inf without one)
    too_close: bool  # margin_deg <= call_deg: the figures and the report say the facing is uncertain


def choose(hypotheses: list[xr.Dataset], config: RefineConfig) -> Choice:
    """The hypothesis kept: of those whose chamfer (Eq. 3) is within ``close`` of the least, the most plausible
    (robust_score); and the runner-up that would give another facing or handedness, with its margin."""
    scores = np.array([h.attrs["chamfer"] for h in hypotheses])
    close = np.flatnonzero(scores <= config.close * scores.min())
    if len(close) == 1 or not all("prior_pose_deg" in hypotheses[i].attrs for i in close):
        return Choice(int(np.argmin(scores)), None, float("inf"), False)
    robust = {int(i): robust_score(hypotheses[i], config) for i in close}
    best = min(robust, key=robust.get)
    attrs = [h.attrs for h in hypotheses]
    other = [i for i in robust if i != best and (attrs[i].get("mirror", False) != attrs[best].get("mirror", False)
                                                 or hyp.angle_deg(attrs[i].get("matched_yaw_deg", 0.0),
                                                                  attrs[best].get("matched_yaw_deg", 0.0)) > 90.0)]
    if not other:
        return Choice(best, None, float("inf"), False)
    runner = min(other, key=robust.get)
    margin = robust[runner] - robust[best]
    return Choice(best, runner, float(margin), bool(margin <= config.call_deg))


def _bodies(phenotype: dict) -> tuple[MeshBody, SolverBody]:
    key = tuple(sorted(phenotype.items()))
    return _BODIES.get_or_make(key, lambda: (lambda b: (b, SolverBody(b)))(mesh_body(Phenotype(**phenotype))))


MIN_MARKERS = 4  # a frame with fewer marker samples tells too little of the body to solve it
MAX_THIN_S = 0.5  # a longer run of such frames is a subject gone from the volume, not a gap to bridge
SPAN_M = (0.05, 5.0)  # a person's markers span this much on a frame (a limb's: tens of centimetres)


def _marker_positions(markers: xr.Dataset) -> np.ndarray:
    positions = markers["position"].transpose("frame", "marker", "xyz").values.astype(np.float64)
    check_take(positions, float(markers.attrs.get("fps", 0.0)), markers["frame"].values)
    return positions


def check_take(positions: np.ndarray, fps: float, frames: np.ndarray) -> None:
    """Refuse a take UUO cannot solve, naming its frames: too few markers on the body, markers whose size is not a
    person's (a unit the file misstates), or a run of frames longer than MAX_THIN_S with fewer than MIN_MARKERS
    samples (the subject left the capture volume).  positions (frame, marker, 3); frames: the take's frame numbers"""
    seen = np.isfinite(positions).all(-1)
    count = seen.sum(1)
    if not seen.any():
        raise SolveError("the take has no marker sample at all; UUO needs markers (check the marker file)")
    if np.median(count) < MIN_MARKERS:
        raise SolveError(f"too few markers on the body to solve: a median of {np.median(count):.0f} per frame over "
                         f"frames {frames[0]}-{frames[-1]}; UUO needs at least {MIN_MARKERS} on the part it solves "
                         "(check that the file holds the take's markers, or choose frames where they are seen)")
    span = np.array([np.ptp(positions[f, seen[f]], axis=0).max() for f in np.flatnonzero(count >= MIN_MARKERS)])
    if not SPAN_M[0] <= np.median(span) <= SPAN_M[1]:
        raise SolveError(f"the markers span a median of {np.median(span):.3g} m on a frame, not a person's "
                         f"{SPAN_M[0]}-{SPAN_M[1]} m: the file's unit is likely misstated (metres labelled as "
                         "millimetres read 1000 times too small); fix the file's unit (C3D POINT:UNITS, TRC Units)")
    thin = count < MIN_MARKERS
    edges = np.diff(np.concatenate([[0], thin.astype(np.int8), [0]]))
    runs = [(a, b) for a, b in zip(np.flatnonzero(edges == 1), np.flatnonzero(edges == -1))
            if fps > 0 and (b - a) / fps > MAX_THIN_S]
    if runs:
        where = ", ".join(f"{frames[a]}-{frames[b - 1]}" for a, b in runs)
        raise SolveError(f"frames {where} have fewer than {MIN_MARKERS} markers for more than {MAX_THIN_S} s: the "
                         "subject left the capture volume (or the markers were lost); keep the frames where the "
                         "subject is seen (the dataset's frames: [start, stop], or takes.<id>.frames)")


def body_fit(ds: xr.Dataset) -> BodyFit:
    """The BodyFit of a body_prior or uuo_body dataset."""
    n_frames, n_bones = ds.sizes["frame"], ds.sizes["bone"]
    world = Rotation.from_quat(ds["bone_rotation"].values.reshape(-1, 4)).as_matrix().reshape(n_frames, n_bones, 3, 3)
    parents = _bodies(ds.attrs["phenotype"])[0].bone_parents
    return BodyFit(local_rotations(world, parents), ds["root"].values.astype(np.float64),
                   np.array([ds.attrs["phenotype"][k] for k in PHENOTYPE_NAMES]))


def floor_plane(markers: np.ndarray, offset_m: float) -> float:
    """The floor's height (m): the capture volume's calibrated ground z = 0, lowered to the markers where they go
    below it (the 1st percentile of the samples' heights, less the marker's offset from the skin), so that a take
    whose origin is not on the floor keeps its markers above it.  markers (frame, marker, 3)"""
    z = markers[..., 2][np.isfinite(markers[..., 2])]
    return float(min(0.0, np.percentile(z, 1.0) - offset_m)) if len(z) else 0.0


def _floor(body: MeshBody, m: np.ndarray, offset_m: float, use: bool) -> Floor | None:
    return Floor(floor_plane(m, offset_m), floor_vertices(body)) if use else None


def _subset(fit: BodyFit, frames: np.ndarray) -> BodyFit:
    return BodyFit(fit.local[frames], fit.root[frames], fit.phenotype)


def chamfer(body: SolverBody, markers: np.ndarray, fit: BodyFit, chain: np.ndarray, cap_m: float,
            vertices: int = 3000) -> float:
    """Eq. (1)/(3): mean squared distance from each marker sample to the closest chain vertex, capped at cap_m."""
    index = evenly(chain, vertices)
    seen = np.isfinite(markers).all(-1)
    _, d2 = closest(np.where(seen[..., None], markers, 0.0), posed_vertices(body, fit, index))
    return float(np.minimum(d2[seen], cap_m ** 2).mean())


def _prior_fit(m: np.ndarray, prior: xr.Dataset, mirror: bool):
    """The prior as a BodyFit (mirrored left-right if asked), its bodies and valid frames."""
    if prior.sizes["frame"] != m.shape[0]:
        raise SolveError(f"the prior has {prior.sizes['frame']} frames and the markers {m.shape[0]}; a prior must "
                         "give a body for every frame of the take")
    body, solver = _bodies(prior.attrs["phenotype"])
    prior_fit = body_fit(prior)
    if mirror:
        prior_fit = hyp.mirrored(prior_fit, hyp.mirror_bones(body.bone_names))
    return body, solver, prior_fit, prior["valid"].values.astype(bool)


def _placed_prior(m: np.ndarray, segments: xr.Dataset, prior: xr.Dataset, yaw_deg: float, matching: MatchConfig,
                  mirror: bool = False, parts: tuple[str, ...] | None = None):
    """§3.4: part matching from the root yaw ``yaw_deg`` (on ``parts`` when the screen found them) and the prior
    placed on the markers by it.
    m (frame, marker, 3) -> (body, solver, match, the placed prior's BodyFit, the prior's valid frames)"""
    body, solver, prior_fit, valid = _prior_fit(m, prior, mirror)
    match = match_parts(m, segments["segment"].values, body,
                        lambda frames, index: posed_vertices(solver, _subset(prior_fit, frames), index),
                        np.radians(yaw_deg), matching, parts)
    local = prior_fit.local.copy()
    local[:, 0] = match.rotation @ local[:, 0]
    start = BodyFit(local, np.einsum("fij,fj->fi", match.rotation, prior_fit.root) + match.translation,
                    prior_fit.phenotype)  # one rotation for the take, a translation per frame
    return body, solver, match, start, valid


def solve_hypothesis(markers: xr.Dataset, segments: xr.Dataset, prior: xr.Dataset,
                     config: HypothesisConfig) -> xr.Dataset:
    """Stage ``uuo_yaw*``: part matching and solver stages 2-4 from one root-yaw hypothesis."""
    return _solve(markers, segments, prior, config, None)


def _solve(markers: xr.Dataset, segments: xr.Dataset, prior: xr.Dataset, config: HypothesisConfig,
           parts: tuple[str, ...] | None) -> xr.Dataset:
    m = _marker_positions(markers)
    body, solver, match, start, valid = _placed_prior(m, segments, prior, config.yaw_deg, config.matching,
                                                      config.mirror, parts)
    chain = part_vertices(body, match.parts)
    floor = _floor(body, m, config.pose_fit.offset_m, config.floor)
    fitted = fit_pose(solver, m, start, start, valid, chain, config.pose_fit, floor)  # stage 2
    vertex, distance = correspond(solver, m, fitted, chain, config.correspondence)  # stage 3
    solved = inverse_kinematics(solver, m, vertex, fitted, start, valid, config.ik, floor) if (vertex >= 0).any() \
        else fitted  # stage 4 (a hypothesis that labels nothing keeps stage 2's body and loses on Eq. 3)
    score = chamfer(solver, m, solved, chain, config.outlier_m)
    stage_joints = {name: posed_heads(solver, f)[:, body.joint_bones()]
                    for name, f in (("matching", start), ("pose_fit", fitted), ("ik", solved))}
    part = np.array([part_of_bone(body.bone_names[body.vertex_bone[v]]) if v >= 0 else "" for v in vertex])
    return body_dataset(markers, body, solver, solved, vertex, distance, stage_joints,
                        {"yaw_deg": float(config.yaw_deg), "mirror": bool(config.mirror), "chamfer": score,
                         "parts": list(match.parts), "matched_yaw_deg": float(np.degrees(match.yaw)),
                         "candidates": match.candidates,
                         "prior_pose_deg": pose_disagreement(body, solved.local, start.local),
                         "side_split": side_split(part, segments["segment"].values),
                         **plausibility(body, solver, solved, config.hinge_tolerance_deg)})


def plausibility(body: MeshBody, solver: SolverBody, fit: BodyFit, tolerance_deg: float) -> dict:
    """A solved body's anatomy (hypotheses.py): its knees and elbows bent against their hinge (degrees, mean over
    frames of the sum over the four) and how clearly it travels backward ([0, 1])."""
    from mocapflow.tasks.shared.kinematics import world_rotations

    heads = posed_heads(solver, fit)
    flexion = hyp.hinge_flexion_deg(body, world_rotations(fit.local, body.bone_parents), heads)
    return {"hyperextension_deg": hyp.hyperextension_deg(flexion, tolerance_deg),
            "backward_travel": hyp.backward_travel(heads[:, body.joint_bones()], JOINT_NAMES)}


def screen_hypotheses(markers: xr.Dataset, segments: xr.Dataset, prior: xr.Dataset,
                      config: ScreenConfig) -> xr.Dataset:
    """Stage ``uuo_screen`` (§3.5.1, widened): the prior placed by part matching's search from every root yaw in
    steps of ``step_deg`` and, unless the prior is left-right symmetric, mirrored; the placements ranked for the
    solve stages (``solve_screened``'s ``rank``): first the best ``keep`` that face apart (hypotheses.distinct),
    then the others by chamfer."""
    m = _marker_positions(markers)
    groups = segments["segment"].values
    body, solver, prior_fit, _ = _prior_fit(m, prior, False)
    bones = hyp.mirror_bones(body.bone_names)
    symmetric = hyp.is_symmetric(solver, prior_fit, bones, config.symmetric_m)

    def skin(fit: BodyFit):
        return lambda frames, index: posed_vertices(solver, _subset(fit, frames), index)

    chains = set()  # §3.4.2's search from the paper's four yaws; each chain also with its sides swapped
    for yaw in config.search_yaws_deg:
        parts = search_parts(m, groups, body, skin(prior_fit), np.radians(yaw), config.matching)[0]
        chains |= {parts, mirror_parts(parts)}
    candidates = []
    for mirror in (False, True) if config.mirror and not symmetric else (False,):
        skinned = skin(hyp.mirrored(prior_fit, bones) if mirror else prior_fit)
        for yaw in hyp.yaws(config.step_deg):
            fits = {parts: try_chain(m, body, skinned, parts, np.radians(yaw), config.matching)
                    for parts in sorted(chains)}
            parts = min(fits, key=lambda p: fits[p][2])
            candidates.append({"yaw_deg": float(yaw), "mirror": mirror, "chamfer": float(fits[parts][2]),
                               "matched_yaw_deg": float(np.degrees(fits[parts][0])) % 360.0,
                               "parts": ",".join(parts)})
    kept = hyp.distinct(candidates, config.keep, config.distinct_deg)
    order = kept + sorted((c for c in candidates if c not in kept), key=lambda c: c["chamfer"])
    return xr.Dataset(
        {name: (("hypothesis",), np.array([c[name] for c in order], dtype=object if name == "parts" else None))
         for name in ("yaw_deg", "mirror", "matched_yaw_deg", "chamfer", "parts")},
        coords={"hypothesis": np.arange(len(order))},
        attrs={"distinct": len(kept), "symmetric_prior": bool(symmetric), "step_deg": float(config.step_deg)})


def solve_screened(markers: xr.Dataset, segments: xr.Dataset, prior: xr.Dataset, screen: xr.Dataset,
                   config: ScreenedConfig) -> xr.Dataset:
    """Stage ``uuo_h*``: solver stages 2-4 from the screen's placement ``rank`` (its yaw, handedness and chain)."""
    if config.rank >= screen.sizes["hypothesis"]:
        raise SolveError(f"rank {config.rank} asks for more placements than the screen made "
                         f"({screen.sizes['hypothesis']}); use a rank below it")
    row = screen.isel(hypothesis=config.rank)
    solve = dataclasses.replace(config.solve, yaw_deg=float(row["matched_yaw_deg"]), mirror=bool(row["mirror"]))
    out = _solve(markers, segments, prior, solve, tuple(str(row["parts"].item()).split(",")))
    return out.assign_attrs(rank=int(config.rank), screen_yaw_deg=float(row["yaw_deg"]))


def pose_disagreement(body: MeshBody, local: np.ndarray, prior_local: np.ndarray) -> float:
    """Mean angle (degrees) between a solve's and the prior's own joint rotations (PRIOR_BONES but the root, which
    placement sets): a body solved turned around or mirrored bends its limbs unlike the prior's.
    local, prior_local (frame, bone, 3, 3)"""
    from mocapflow.tasks.uuo.prior import PRIOR_BONES

    bones = [i for i, n in enumerate(body.bone_names) if n in PRIOR_BONES and i > 0]
    relative = np.swapaxes(prior_local[:, bones], -1, -2) @ local[:, bones]
    cos = np.clip((np.trace(relative, axis1=-2, axis2=-1) - 1.0) / 2.0, -1.0, 1.0)
    return float(np.degrees(np.arccos(cos)).mean())


def side_split(parts: np.ndarray, segments: np.ndarray) -> float:
    """The share of sided labels (left_*/right_*) of the rigid groups against their group's majority side: a rigid
    group rides one bone, so its markers are on one side.  parts, segments (marker,) -> [0, 1]"""
    side = part_sides(parts)
    against = total = 0
    for group in np.unique(segments[segments >= 0]):
        sided = side[(segments == group) & (side != 0)]
        if len(sided) >= 2:
            total += len(sided)
            against += len(sided) - max((sided == 1).sum(), (sided == -1).sum())
    return float(against / total) if total else 0.0


@dataclass(frozen=True)
class RigidPriorConfig:
    yaws_deg: tuple[float, ...] = (0.0, 90.0, 180.0, 270.0)  # the same hypotheses as the solver's
    matching: MatchConfig = field(default_factory=MatchConfig)
    correspondence: CorrespondenceConfig = field(default_factory=CorrespondenceConfig)
    outlier_m: float = 0.1


def rigid_prior(markers: xr.Dataset, segments: xr.Dataset, prior: xr.Dataset, config: RigidPriorConfig) -> xr.Dataset:
    """Stage ``rigid_prior``: the baseline "prior only + rigid registration" (the paper's HMR2.0+RR of Tables 1
    and 2, aligned by its part localization, Fig. 7): the prior placed on the markers by part matching from each
    yaw, the placement of least chamfer (Eq. 3) kept, no pose solved; each trajectory's vertex on it by Eq. (6)."""
    if not config.yaws_deg:
        raise SolveError("rigid_prior: yaws_deg is empty; give at least one root yaw, e.g. [0, 90, 180, 270]")
    m = _marker_positions(markers)
    best = None
    for yaw in config.yaws_deg:
        body, solver, match, start, _ = _placed_prior(m, segments, prior, yaw, config.matching)
        chain = part_vertices(body, match.parts)
        score = chamfer(solver, m, start, chain, config.outlier_m)  # Eq. (3)
        if best is None or score < best[0]:
            best = (score, yaw, body, solver, match, start, chain)
    score, yaw, body, solver, match, start, chain = best
    vertex, distance = correspond(solver, m, start, chain, config.correspondence)  # Eq. (6)
    return body_dataset(markers, body, solver, start, vertex, distance,
                        {"matching": posed_heads(solver, start)[:, body.joint_bones()]},
                        {"yaw_deg": float(yaw), "chamfer": score, "parts": list(match.parts),
                         "matched_yaw_deg": float(np.degrees(match.yaw)), "candidates": match.candidates})


def _refine(markers: xr.Dataset, hypotheses: list[xr.Dataset], config: RefineConfig) -> xr.Dataset:
    scores = [h.attrs["chamfer"] for h in hypotheses]
    choice = choose(hypotheses, config)  # Eq. (3), the close ones told apart
    best = hypotheses[choice.index]
    if choice.too_close:
        runner = hypotheses[choice.runner_up]
        logger.warning("too close to call: the hypothesis kept (yaw %.0f, %s) and one facing or sided otherwise "
                       "(yaw %.0f, %s) score within %.1f deg of each other; the solve's facing is uncertain",
                       best.attrs["matched_yaw_deg"], "mirrored" if best.attrs.get("mirror") else "as the prior",
                       runner.attrs["matched_yaw_deg"],
                       "mirrored" if runner.attrs.get("mirror") else "as the prior", choice.margin_deg)
    m = _marker_positions(markers)
    body, solver = _bodies(best.attrs["phenotype"])
    solved = body_fit(best)
    chain = part_vertices(body, tuple(best.attrs["parts"]))
    valid = np.ones(m.shape[0], bool)
    vertex, distance = correspond(solver, m, solved, chain, config.correspondence)  # stage 5: stage 3 again ...
    if (vertex >= 0).any():
        floor = _floor(body, m, config.ik.offset_m, config.floor)
        refined = inverse_kinematics(solver, m, vertex, solved, solved, valid, config.ik, floor)  # ... and 4, anchored
    else:  # no trajectory near the chosen body: it stays as stage 4 left it, every marker unlabelled
        logger.warning("no marker trajectory lies within %.2f m of the chosen hypothesis' body (yaw %.0f): the body "
                       "is kept unrefined and every trajectory unlabelled; check that the markers and the prior "
                       "show the same take", config.correspondence.offset_m + config.correspondence.reject_m,
                       best.attrs["yaw_deg"])
        refined = solved
    stage_joints = {name: best["stage_joints"].sel(stage=name).values for name in ("matching", "pose_fit", "ik")}
    stage_joints["refined"] = posed_heads(solver, refined)[:, body.joint_bones()]
    return body_dataset(markers, body, solver, refined, vertex, distance, stage_joints,
                        {**best.attrs, "hypothesis_chamfer": [float(s) for s in scores],
                         "hypotheses_deg": [float(h.attrs.get("matched_yaw_deg", h.attrs["yaw_deg"]))
                                            for h in hypotheses],
                         "hypotheses_mirror": [bool(h.attrs.get("mirror", False)) for h in hypotheses],
                         "chosen": int(choice.index), "too_close": bool(choice.too_close),
                         **({} if choice.runner_up is None else
                            {"runner_up": int(choice.runner_up), "call_margin_deg": float(choice.margin_deg)})})


def best_hypothesis(markers: xr.Dataset, h0: xr.Dataset, h1: xr.Dataset, h2: xr.Dataset, h3: xr.Dataset,
                    config: RefineConfig) -> xr.Dataset:
    """Stage ``uuo_solve``: of four solved hypotheses (four root yaws, or the screen's four best placements), the
    one of least chamfer (Eq. 3), the close ones told apart by plausibility, refined (stage 5)."""
    return _refine(markers, [h0, h1, h2, h3], config)


def single_hypothesis(markers: xr.Dataset, h0: xr.Dataset, config: RefineConfig) -> xr.Dataset:
    """Stage ``uuo_single``: one hypothesis, refined (the paper's "- MHT" ablation, Table 3)."""
    return _refine(markers, [h0], config)


def body_dataset(markers: xr.Dataset, body: MeshBody, solver: SolverBody, fit: BodyFit, vertex: np.ndarray,
                 distance: np.ndarray, stage_joints: dict[str, np.ndarray], attrs: dict) -> xr.Dataset:
    """A uuo_body dataset: the body over the take, each stage's joints, each trajectory's vertex and part."""
    from mocapflow.tasks.shared.kinematics import world_rotations

    n_frames = fit.root.shape[0]
    joint_bones = body.joint_bones()
    heads = posed_heads(solver, fit)
    world = world_rotations(fit.local, body.bone_parents)
    quats = Rotation.from_matrix(world.reshape(-1, 3, 3)).as_quat().reshape(n_frames, -1, 4)
    joints = np.full((len(STAGES), n_frames, len(JOINT_NAMES), 3), np.nan, np.float32)  # NaN: a stage not run
    for name, values in stage_joints.items():
        joints[STAGES.index(name)] = values
    part = np.array([part_of_bone(body.bone_names[body.vertex_bone[v]]) if v >= 0 else "" for v in vertex],
                    dtype=object)
    phenotype = dict(zip(PHENOTYPE_NAMES, map(float, fit.phenotype)))
    return xr.Dataset(
        {"bone_rotation": (("frame", "bone", "quat"), quats), "root": (("frame", "xyz"), fit.root),
         "joints": (("frame", "joint", "xyz"), heads[:, joint_bones].astype(np.float32)),
         "bone_heads": (("frame", "bone", "xyz"), heads.astype(np.float32)),
         "stage_joints": (("stage", "frame", "joint", "xyz"), joints),
         "vertex": (("marker",), vertex.astype(np.int64)), "part": (("marker",), part),
         "marker_distance": (("marker",), distance.astype(np.float64))},
        coords={"frame": markers["frame"].values, "bone": np.array(body.bone_names, dtype=object),
                "joint": np.array(JOINT_NAMES, dtype=object), "marker": markers["marker"].values,
                "xyz": np.array(["x", "y", "z"], dtype=object), "quat": np.array(["x", "y", "z", "w"], dtype=object),
                "stage": np.array(STAGES, dtype=object)},
        attrs={**attrs, "phenotype": phenotype, "fps": float(markers.attrs.get("fps", 0.0))})


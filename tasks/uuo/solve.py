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
from mocapflow.tasks.uuo.ik import IKConfig, inverse_kinematics
from mocapflow.tasks.uuo.matching import MatchConfig, closest, evenly, match_parts, part_vertices
from mocapflow.tasks.uuo.pose_fit import PoseFitConfig, fit_pose

logger = logging.getLogger(__name__)

STAGES = ("matching", "pose_fit", "ik", "refined")
_BODIES: BoundedCache[tuple, tuple] = BoundedCache(2)


class SolveError(ValueError):
    """Inputs the solver cannot use."""


@dataclass(frozen=True)
class HypothesisConfig:
    yaw_deg: float = 0.0  # the hypothesis' starting root yaw (§3.5.1)
    matching: MatchConfig = field(default_factory=MatchConfig)
    pose_fit: PoseFitConfig = field(default_factory=PoseFitConfig)
    correspondence: CorrespondenceConfig = field(default_factory=CorrespondenceConfig)
    ik: IKConfig = field(default_factory=IKConfig)
    outlier_m: float = 0.1  # a sample's distance is capped here in the chamfer of Eq. (3), so ghosts do not choose
    floor: bool = True  # keep the skin above the floor plane (floor_plane)


@dataclass(frozen=True)
class RefineConfig:
    correspondence: CorrespondenceConfig = field(default_factory=CorrespondenceConfig)
    ik: IKConfig = field(default_factory=IKConfig)
    close: float = 1.5  # hypotheses whose chamfer is within this factor of the least are close: among them ...
    split_deg: float = 100.0  # ... the least prior_pose_deg + split_deg * side_split wins (not turned or mirrored)
    floor: bool = True  # keep the skin above the floor plane (floor_plane)

    def __post_init__(self):
        if self.close < 1.0 or self.split_deg < 0:
            raise SolveError(f"refine needs close >= 1 and split_deg >= 0, got {self.close} and {self.split_deg}")


def choose(hypotheses: list[xr.Dataset], config: RefineConfig) -> int:
    """The hypothesis kept: of those whose chamfer (Eq. 3) is within ``close`` of the least, the one whose pose
    agrees best with the prior's own joint rotations and whose rigid groups keep to one side."""
    scores = np.array([h.attrs["chamfer"] for h in hypotheses])
    close = np.flatnonzero(scores <= config.close * scores.min())
    if len(close) == 1 or not all("prior_pose_deg" in hypotheses[i].attrs for i in close):
        return int(np.argmin(scores))
    robust = [hypotheses[i].attrs["prior_pose_deg"] + config.split_deg * hypotheses[i].attrs["side_split"]
              for i in close]
    return int(close[int(np.argmin(robust))])


def _bodies(phenotype: dict) -> tuple[MeshBody, SolverBody]:
    key = tuple(sorted(phenotype.items()))
    return _BODIES.get_or_make(key, lambda: (lambda b: (b, SolverBody(b)))(mesh_body(Phenotype(**phenotype))))


def _marker_positions(markers: xr.Dataset) -> np.ndarray:
    positions = markers["position"].transpose("frame", "marker", "xyz").values.astype(np.float64)
    if not np.isfinite(positions).all(-1).any():
        raise SolveError("the take has no marker sample at all; UUO needs markers (check the marker file)")
    return positions


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


def _placed_prior(m: np.ndarray, segments: xr.Dataset, prior: xr.Dataset, yaw_deg: float, matching: MatchConfig):
    """§3.4: part matching from the root yaw ``yaw_deg`` and the prior placed on the markers by it.
    m (frame, marker, 3) -> (body, solver, match, the placed prior's BodyFit, the prior's valid frames)"""
    if prior.sizes["frame"] != m.shape[0]:
        raise SolveError(f"the prior has {prior.sizes['frame']} frames and the markers {m.shape[0]}; a prior must "
                         "give a body for every frame of the take")
    body, solver = _bodies(prior.attrs["phenotype"])
    prior_fit = body_fit(prior)
    valid = prior["valid"].values.astype(bool)
    match = match_parts(m, segments["segment"].values, body,
                        lambda frames, index: posed_vertices(solver, _subset(prior_fit, frames), index),
                        np.radians(yaw_deg), matching)
    local = prior_fit.local.copy()
    local[:, 0] = match.rotation @ local[:, 0]
    start = BodyFit(local, np.einsum("fij,fj->fi", match.rotation, prior_fit.root) + match.translation,
                    prior_fit.phenotype)  # one rotation for the take, a translation per frame
    return body, solver, match, start, valid


def solve_hypothesis(markers: xr.Dataset, segments: xr.Dataset, prior: xr.Dataset,
                     config: HypothesisConfig) -> xr.Dataset:
    """Stage ``uuo_yaw*``: part matching and solver stages 2-4 from one root-yaw hypothesis."""
    m = _marker_positions(markers)
    body, solver, match, start, valid = _placed_prior(m, segments, prior, config.yaw_deg, config.matching)
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
                        {"yaw_deg": float(config.yaw_deg), "chamfer": score, "parts": list(match.parts),
                         "matched_yaw_deg": float(np.degrees(match.yaw)), "candidates": match.candidates,
                         "prior_pose_deg": pose_disagreement(body, solved.local, start.local),
                         "side_split": side_split(part, segments["segment"].values)})


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
    best = hypotheses[choose(hypotheses, config)]  # Eq. (3), the close ones told apart
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
                         "hypotheses_deg": [float(h.attrs["yaw_deg"]) for h in hypotheses]})


def best_hypothesis(markers: xr.Dataset, yaw0: xr.Dataset, yaw90: xr.Dataset, yaw180: xr.Dataset,
                    yaw270: xr.Dataset, config: RefineConfig) -> xr.Dataset:
    """Stage ``uuo_solve``: the hypothesis of least chamfer (Eq. 3) of four, refined (stage 5)."""
    return _refine(markers, [yaw0, yaw90, yaw180, yaw270], config)


def single_hypothesis(markers: xr.Dataset, yaw0: xr.Dataset, config: RefineConfig) -> xr.Dataset:
    """Stage ``uuo_single``: one hypothesis, refined (the paper's "- MHT" ablation, Table 3)."""
    return _refine(markers, [yaw0], config)


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


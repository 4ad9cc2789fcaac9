"""Anny fitted to a take's points at known places on its skin: the body solve every system shares.

The suit knows each corner's place (Chen, Park, Macit, Kavan 2021, §5), DeepMoCap each reflector's (a patch's point
of the skin, a strap's limb centre), UUO each labelled marker's vertex (Milef et al. 2024, Eq. 7-8): the posed
position of a place is a function of the pose and the phenotype, and the house's Levenberg-Marquardt fitter
(tasks/shared/body_fit) minimises

    sum_observed c_fn ||LBS(place) - p||^2 / sigma_p^2  +  sum_bones |log(A_b^T L_b)|^2 / sigma_theta^2
                                                        +  ||phenotype - start||^2 / sigma_beta^2

(c_fn a point's confidence, 1 where none is given; the second term UUO's E_Theta, each bone's rotation from an
anchor pose A_b, holding bones no point sees, the root's rotation free; the third E_beta). Three stages:

1. key frames (every ``key_stride``-th fitted frame), each from the rest pose placed rigidly on its observed trunk
   points (Kabsch), at the start phenotype, E_Theta toward the rest pose; roughly;
2. the phenotype, once per take, jointly with the poses of up to ``shape_frames`` key frames;
3. every fitted frame with the phenotype fixed, ``chunk`` frames at a time, from its key frames' poses
   interpolated, E_Theta now toward that interpolation (a limb no point sees in a frame follows its key frames
   rather than the rest pose).

A frame with fewer than ``min_points`` observed points is not fitted (its pose is ill-posed): it borrows its
neighbours' pose, each bone's rotation interpolated (slerp) and the root's position linearly between the nearest
fitted frames before and after it (the nearest one at the take's ends).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.spatial.transform import Rotation

from mocapflow.tasks.shared import body_fit as lm
from mocapflow.tasks.shared.kinematics import rigid_fit
from mocapflow.tasks.shared.cache import BoundedCache
from mocapflow.tasks.shared.mesh_body import PHENOTYPE_NAMES, Phenotype, mesh_body, part_of_bone
from mocapflow.tasks.shared.solver_body import BodyFit, SolverBody

CONVERGED = 1e-3  # relative energy decrease at which an iteration stops the solve
ROUGH = 1e-2  # the same for the key frames' first poses, at the start phenotype (the shape's fit refines them)
_REFERENCE: BoundedCache[str, SolverBody] = BoundedCache(1)


class PlaceFitError(ValueError):
    """Points, places on the body or settings the body fit cannot use."""


@dataclass(frozen=True)
class PlaceFitConfig:
    point_sigma_m: float = 0.001  # sigma_p: the points' weight, 1 / sigma_p^2 per squared metre
    pose_sigma_rad: float = 1.0  # sigma_theta: E_Theta, each bone's rotation from the anchor pose (not the root's)
    shape_sigma: float = 0.3  # sigma_beta: E_beta, the phenotype from ``start``
    start: Phenotype = field(default_factory=Phenotype)  # the phenotype the fit starts from
    min_points: int = 30  # fewer observed points: the frame borrows its neighbours' pose
    key_stride: int = 8  # every so many frames posed first, from the rest pose; the others start between them
    shape_frames: int = 20  # key frames the phenotype is fitted on
    iterations: int = 30  # Levenberg-Marquardt iterations, at most, per stage
    chunk: int = 8  # frames solved at once (bounded memory; small arrays stay in cache)
    trunk: tuple[str, ...] = ("torso", "hips")  # parts whose points place the rest pose

    def __post_init__(self):
        if min(self.point_sigma_m, self.pose_sigma_rad, self.shape_sigma) <= 0 or self.min_points < 3 \
                or min(self.key_stride, self.shape_frames, self.chunk, self.iterations) < 1:
            raise PlaceFitError(f"body fit settings out of range: sigmas > 0, min_points >= 3, key_stride, "
                                f"shape_frames, chunk, iterations >= 1 (got {self})")


@dataclass(frozen=True)
class PlacedBody:
    fit: BodyFit  # local rotations (frame, bone, 3, 3), root (frame, 3), phenotype (6,)
    weights: np.ndarray  # (place, bone) skinning weights
    fitted: np.ndarray  # (frame,) bool: fitted to its own points (False: posed from its neighbours)


def reference_body() -> SolverBody:
    """Anny's rig at the default phenotype (its topology; a fit's phenotype is its own), made once per process."""
    return _REFERENCE.get_or_make("reference", lambda: SolverBody(mesh_body(Phenotype())))


def phenotype_vector(p: Phenotype) -> np.ndarray:
    return np.array([getattr(p, name) for name in PHENOTYPE_NAMES], np.float64)


def _terms(points: np.ndarray, confidence: np.ndarray, anchor: np.ndarray, config: PlaceFitConfig) -> lm.Terms:
    """The module's energy for ``points`` (frame, place, 3), E_Theta toward ``anchor`` (frame, bone, 3, 3)."""
    seen = np.isfinite(points).all(-1)
    data = lm.Points(np.arange(points.shape[1]), np.where(seen[..., None], points, 0.0),
                     seen * confidence / config.point_sigma_m ** 2)  # Eq. (8), Milef et al. 2024, zero offset
    prior = lm.PosePrior(anchor, np.full(len(points), 1.0 / config.pose_sigma_rad ** 2))  # E_Theta, Eq. (5)
    return lm.Terms(data, prior, shape_anchor=phenotype_vector(config.start),
                    shape_weight=1.0 / config.shape_sigma ** 2)  # E_beta, Eq. (2)


def placed_rest_pose(points: np.ndarray, rest: np.ndarray, rest_root: np.ndarray,
                     trunk: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Each frame's start: the rest body turned and moved onto its observed points (Kabsch on the trunk's, or on
    all when fewer than 3 trunk points are seen).  points (frame, place, 3), rest (place, 3), rest_root (3,)
    the root's rest head, trunk (place,) bool -> root rotation (frame, 3, 3), root head (frame, 3)"""
    rotation = np.zeros((len(points), 3, 3))
    root = np.zeros((len(points), 3))
    seen = np.isfinite(points).all(-1)
    for f in range(len(points)):
        use = seen[f] & trunk if (seen[f] & trunk).sum() >= 3 else seen[f]
        rotation[f], t = rigid_fit(rest[use], points[f, use])  # p = R x + t (Kabsch)
        root[f] = rotation[f] @ rest_root + t  # where the rigidly moved rest body puts the root's head
    return rotation, root


def _start(body: SolverBody, points: np.ndarray, rest: lm.Rest, trunk: np.ndarray, phenotype: np.ndarray) -> BodyFit:
    """Each frame's rest pose placed on its observed points (``placed_rest_pose``)."""
    rotation, root = placed_rest_pose(points, rest.points[0].numpy(), rest.heads[0].numpy(), trunk)
    local = np.tile(np.eye(3), (len(points), body.n_bones, 1, 1))
    local[:, 0] = rotation
    return BodyFit(local, root, phenotype)


def borrow_poses(fit: BodyFit, fitted: np.ndarray) -> BodyFit:
    """Frames not fitted take their neighbours' pose: per bone slerp and the root lerp between the nearest fitted
    frames before and after (the nearest one past the ends).  fitted (frame,) bool -> BodyFit"""
    frames = np.arange(len(fitted))
    good = np.flatnonzero(fitted)
    after = np.clip(np.searchsorted(good, frames), 0, len(good) - 1)
    before = np.clip(after - (good[after] > frames), 0, len(good) - 1)
    lo, hi = good[before], good[after]
    alpha = np.where(hi > lo, (frames - lo) / np.maximum(hi - lo, 1), 0.0)  # (frame,)
    r_lo = Rotation.from_matrix(fit.local[lo].reshape(-1, 3, 3))
    r_hi = Rotation.from_matrix(fit.local[hi].reshape(-1, 3, 3))
    step = (r_lo.inv() * r_hi).as_rotvec() * np.repeat(alpha, fit.local.shape[1])[:, None]
    local = (r_lo * Rotation.from_rotvec(step)).as_matrix().reshape(fit.local.shape)
    root = fit.root[lo] + alpha[:, None] * (fit.root[hi] - fit.root[lo])
    local[good], root[good] = fit.local[good], fit.root[good]
    return BodyFit(local, root, fit.phenotype)


def _evenly(frames: np.ndarray, count: int) -> np.ndarray:
    return frames[np.unique(np.linspace(0, len(frames) - 1, min(count, len(frames))).round().astype(int))]


def _trunk(body: SolverBody, places: lm.Places, parts: tuple[str, ...]) -> np.ndarray:
    part = np.array([part_of_bone(n) for n in body.body.bone_names])
    return np.isin(part[body.body.vertex_bone[places.vertices[:, 0]]], parts)


def _key_frames(body: SolverBody, points: np.ndarray, confidence: np.ndarray, places: lm.Places, skin: lm.Skin,
                config: PlaceFitConfig) -> BodyFit:
    """The key frames posed from the rest pose at the start phenotype (roughly), then the phenotype fitted with the
    poses of up to ``shape_frames`` of them.  points (key frame, place, 3)"""
    phenotype = phenotype_vector(config.start)
    rest = lm.rest_of(body, phenotype, (places,))
    start = _start(body, points, rest, _trunk(body, places, config.trunk), phenotype)
    rest_pose = np.tile(np.eye(3), start.local.shape[:2] + (1, 1))  # E_Theta toward the rest pose
    keyed = lm.solve_poses(body, places, _terms(points, confidence, rest_pose, config), lm.State.of(start),
                           config.iterations, ROUGH, config.chunk, skin)
    shaped = _evenly(np.arange(len(points)), config.shape_frames)
    state = lm.solve_take(body, places, _terms(points[shaped], confidence[shaped], rest_pose[shaped], config),
                          lm.State(keyed.local[shaped], keyed.root[shaped], phenotype), config.iterations, CONVERGED,
                          skin)
    local, root = keyed.local.numpy().copy(), keyed.root.numpy().copy()
    local[shaped], root[shaped] = state.local.numpy(), state.root.numpy()
    return BodyFit(local, root, state.phenotype)


def _check(points: np.ndarray, confidence: np.ndarray, places: lm.Places) -> None:
    if points.ndim != 3 or points.shape[2] != 3 or points.shape[1] != len(places.vertices):
        raise PlaceFitError(f"the body fit takes points (frame, place, 3) for its {len(places.vertices)} places, "
                            f"got {points.shape}")
    if confidence.shape != points.shape[:2] or not np.isfinite(confidence).all() or (confidence < 0).any():
        raise PlaceFitError(f"point confidences must be finite and >= 0, one per (frame, place) {points.shape[:2]}, "
                            f"got shape {confidence.shape}")
    if np.isinf(points).any():
        raise PlaceFitError("point positions hold infinite values; mark unobserved points with NaN")


def fit_places(body: SolverBody, points: np.ndarray, places: lm.Places, config: PlaceFitConfig = PlaceFitConfig(),
               confidence: np.ndarray | None = None) -> PlacedBody:
    """Fit Anny to a take's points at known ``places`` of its rest mesh (see the module's text).

    points (frame, place, 3) NaN where unobserved; confidence (frame, place) >= 0, each point's weight relative to
    ``1 / point_sigma_m^2`` (1 where not given).
    """
    points = np.asarray(points, np.float64)
    confidence = np.ones(points.shape[:2]) if confidence is None else np.asarray(confidence, np.float64)
    _check(points, confidence, places)
    points = np.where((confidence > 0)[..., None], points, np.nan)
    counts = np.isfinite(points).all(-1).sum(1)
    fitted = counts >= config.min_points  # (frame,)
    if not fitted.any():
        raise PlaceFitError(f"no frame has {config.min_points} observed points (most: {counts.max(initial=0)}); the "
                            "body cannot be fitted (lower min_points or check the observations)")
    weights = lm.place_weights(body, places)
    skin, good = lm.skin_of(body, weights), np.flatnonzero(fitted)
    keys = np.union1d(good[::config.key_stride], good[-1:])
    keyed = _key_frames(body, points[keys], confidence[keys], places, skin, config)
    start = _spread(keyed, keys, len(points), np.isin(np.arange(len(points)), keys))
    between = BodyFit(start.local[good], start.root[good], start.phenotype)  # E_Theta toward the key frames' poses
    solved = lm.solve_poses(body, places, _terms(points[good], confidence[good], between.local, config),
                            lm.State.of(between), config.iterations, CONVERGED, config.chunk, skin)
    local, root = start.local, start.root
    local[good], root[good] = solved.local.numpy(), solved.root.numpy()
    return PlacedBody(borrow_poses(BodyFit(local, root, start.phenotype), fitted), weights, fitted)


def _spread(keyed: BodyFit, keys: np.ndarray, frames: int, known: np.ndarray) -> BodyFit:
    """The key frames' poses interpolated to every frame (``borrow_poses``).  -> BodyFit (frame, ...)"""
    local = np.tile(np.eye(3), (frames, keyed.local.shape[1], 1, 1))
    root = np.zeros((frames, 3))
    local[keys], root[keys] = keyed.local, keyed.root
    return borrow_poses(BodyFit(local, root, keyed.phenotype), known)

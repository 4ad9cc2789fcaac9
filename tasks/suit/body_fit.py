"""The body model under the suit's corners (Chen, Park, Macit, Kavan 2021, §5): a skinned body fitted to the
observed corners, for hole filling (tasks/suit/fill) to unpose them into the rest pose and repose the filled ones.

The paper fits STAR, refined per actor; here the body is Anny, fitted by the house's Levenberg-Marquardt body fitter
(tasks/shared/body_fit) as UUO's inverse kinematics fits markers with known vertices (Milef et al. 2024, Eq. 7-8,
zero marker offset): every corner's place on the rest body is known, a point (face, barycentric) of
``MeshBody.faces``, so its posed position is a function of the pose and the phenotype, and the fit minimises

    sum_observed ||LBS(corner) - p||^2 / sigma_p^2  +  sum_bones |log(A_b^T L_b)|^2 / sigma_theta^2
                                                    +  ||phenotype - start||^2 / sigma_beta^2

(the second term UUO's E_Theta, each bone's rotation from an anchor pose A_b, holding bones no corner sees, the
root's rotation free; the third E_beta). A corner is skinned as one point with its own weights, the barycentric
blend of its face's vertices' Anny weights, so that ``fill.skinning_transforms`` / ``unpose`` / ``repose`` apply to
it unchanged; this differs from blending the three skinned vertices by a second-order term (well under a
millimetre; the non-articulated displacements absorb it). Three stages:

1. key frames (every ``key_stride``-th fitted frame), each from the rest pose placed rigidly on its observed trunk
   corners (Kabsch), at the start phenotype, E_Theta toward the rest pose; roughly;
2. the phenotype, once per take, jointly with the poses of up to ``shape_frames`` key frames;
3. every fitted frame with the phenotype fixed, ``chunk`` frames at a time, from its key frames' poses
   interpolated, E_Theta now toward that interpolation (a limb no corner sees in a frame follows its key frames
   rather than the rest pose).

A frame with fewer than ``min_corners`` observed corners is not fitted (its pose is ill-posed): it borrows its
neighbours' pose, each bone's rotation interpolated (slerp) and the root's position linearly between the nearest
fitted frames before and after it (the nearest one at the take's ends). The result is in the rest body's own frame
(feet at z = 0, as ``mesh_body``'s): rest corners and, per frame, each bone's rest -> posed 4x4 transform
[M_k | h_k - M_k r_k].
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.spatial.transform import Rotation

from mocapflow.tasks.shared import body_fit as lm
from mocapflow.tasks.shared.kinematics import rigid_fit
from mocapflow.tasks.shared.mesh_body import PHENOTYPE_NAMES, Phenotype, part_of_bone
from mocapflow.tasks.shared.solver_body import BodyFit, SolverBody

CONVERGED = 1e-3  # relative energy decrease at which an iteration stops the solve
ROUGH = 1e-2  # the same for the key frames' first poses, at the start phenotype (the shape's fit refines them)


class BodyFitError(ValueError):
    """Corners, places on the body or settings the suit's body fit cannot use."""


@dataclass(frozen=True)
class BodyFitConfig:
    point_sigma_m: float = 0.001  # sigma_p: the corners' weight, 1 / sigma_p^2 per squared metre
    pose_sigma_rad: float = 1.0  # sigma_theta: E_Theta, each bone's rotation from the anchor pose (not the root's)
    shape_sigma: float = 0.3  # sigma_beta: E_beta, the phenotype from ``start``
    start: Phenotype = field(default_factory=Phenotype)  # the phenotype the fit starts from
    min_corners: int = 30  # fewer observed corners: the frame borrows its neighbours' pose
    key_stride: int = 8  # every so many frames posed first, from the rest pose; the others start between them
    shape_frames: int = 20  # key frames the phenotype is fitted on
    iterations: int = 30  # Levenberg-Marquardt iterations, at most, per stage
    chunk: int = 8  # frames solved at once (bounded memory; small arrays stay in cache)
    trunk: tuple[str, ...] = ("torso", "hips")  # parts whose corners place the rest pose

    def __post_init__(self):
        if min(self.point_sigma_m, self.pose_sigma_rad, self.shape_sigma) <= 0 or self.min_corners < 3 \
                or min(self.key_stride, self.shape_frames, self.chunk, self.iterations) < 1:
            raise BodyFitError(f"body fit settings out of range: sigmas > 0, min_corners >= 3, key_stride, "
                               f"shape_frames, chunk, iterations >= 1 (got {self})")


@dataclass(frozen=True)
class SuitBody:
    fit: BodyFit  # local rotations (frame, bone, 3, 3), root (frame, 3), phenotype (6,)
    bone_transforms: np.ndarray  # (frame, bone, 4, 4) rest -> posed
    weights: np.ndarray  # (corner, bone) skinning weights
    rest: np.ndarray  # (corner, 3) rest positions on the fitted body, the frame of bone_transforms
    borrowed: np.ndarray  # (frame,) bool: posed from its neighbours (too few corners observed)


# --- corners on the body ---------------------------------------------------------------------------------------------


def _check_places(body: SolverBody, points: np.ndarray, face: np.ndarray, barycentric: np.ndarray) -> None:
    if points.ndim != 3 or points.shape[2] != 3 or face.shape != (points.shape[1],) \
            or barycentric.shape != (points.shape[1], 2):
        raise BodyFitError(f"the body fit takes points (frame, corner, 3), face (corner,) and barycentric "
                           f"(corner, 2), got {points.shape}, {face.shape} and {barycentric.shape}")
    if not np.issubdtype(face.dtype, np.integer) or face.min(initial=0) < 0 \
            or face.max(initial=0) >= len(body.body.faces):
        raise BodyFitError(f"corner faces must be indices into the body's {len(body.body.faces)} faces, got "
                           f"{face.dtype} in [{face.min(initial=0)}, {face.max(initial=0)}]")
    if not np.isfinite(barycentric).all() or (barycentric < -1e-9).any() or (barycentric.sum(1) > 1 + 1e-9).any():
        raise BodyFitError("barycentric coordinates (u, v) must be finite with u, v >= 0 and u + v <= 1 (the "
                           "point (1-u-v) V0 + u V1 + v V2 of its face)")
    if np.isinf(points).any():
        raise BodyFitError("corner positions hold infinite values; mark unobserved corners with NaN")


def corner_weights(body: SolverBody, face: np.ndarray, barycentric: np.ndarray) -> np.ndarray:
    """Skinning weights of each corner: the barycentric blend of its face's vertices' Anny weights.
    face (corner,), barycentric (corner, 2) -> (corner, bone)"""
    return lm.place_weights(body, lm.Places.of_faces(body.body, face, barycentric))


def _phenotype(p: Phenotype) -> np.ndarray:
    return np.array([getattr(p, name) for name in PHENOTYPE_NAMES], np.float64)


def _terms(points: np.ndarray, anchor: np.ndarray, config: BodyFitConfig) -> lm.Terms:
    """The module's energy for ``points`` (frame, corner, 3), E_Theta toward ``anchor`` (frame, bone, 3, 3)."""
    seen = np.isfinite(points).all(-1)
    data = lm.Points(np.arange(points.shape[1]), np.where(seen[..., None], points, 0.0),
                     seen / config.point_sigma_m ** 2)  # Eq. (8), Milef et al. 2024, zero marker offset
    prior = lm.PosePrior(anchor, np.full(len(points), 1.0 / config.pose_sigma_rad ** 2))  # E_Theta, Eq. (5)
    return lm.Terms(data, prior, shape_anchor=_phenotype(config.start),
                    shape_weight=1.0 / config.shape_sigma ** 2)  # E_beta, Eq. (2)


# --- the take --------------------------------------------------------------------------------------------------------


def placed_rest_pose(points: np.ndarray, rest: np.ndarray, rest_root: np.ndarray,
                     trunk: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Each frame's start: the rest body turned and moved onto its observed corners (Kabsch on the trunk's, or on
    all when fewer than 3 trunk corners are seen).  points (frame, corner, 3), rest (corner, 3), rest_root (3,)
    the root's rest head, trunk (corner,) bool -> root rotation (frame, 3, 3), root head (frame, 3)"""
    rotation = np.zeros((len(points), 3, 3))
    root = np.zeros((len(points), 3))
    seen = np.isfinite(points).all(-1)
    for f in range(len(points)):
        use = seen[f] & trunk if (seen[f] & trunk).sum() >= 3 else seen[f]
        rotation[f], t = rigid_fit(rest[use], points[f, use])  # p = R x + t (Kabsch)
        root[f] = rotation[f] @ rest_root + t  # where the rigidly moved rest body puts the root's head
    return rotation, root


def _start(body: SolverBody, points: np.ndarray, rest: lm.Rest, trunk: np.ndarray, phenotype: np.ndarray) -> BodyFit:
    """Each frame's rest pose placed on its observed corners (``placed_rest_pose``)."""
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


def _key_frames(body: SolverBody, points: np.ndarray, places: lm.Places, skin: lm.Skin,
                config: BodyFitConfig) -> BodyFit:
    """The key frames posed from the rest pose at the start phenotype (roughly), then the phenotype fitted with the
    poses of up to ``shape_frames`` of them.  points (key frame, corner, 3)"""
    phenotype = _phenotype(config.start)
    rest = lm.rest_of(body, phenotype, (places,))
    start = _start(body, points, rest, _trunk(body, places, config.trunk), phenotype)
    rest_pose = np.tile(np.eye(3), start.local.shape[:2] + (1, 1))  # E_Theta toward the rest pose
    keyed = lm.solve_poses(body, places, _terms(points, rest_pose, config), lm.State.of(start), config.iterations,
                           ROUGH, config.chunk, skin)
    shaped = _evenly(np.arange(len(points)), config.shape_frames)
    state = lm.solve_take(body, places, _terms(points[shaped], rest_pose[shaped], config),
                          lm.State(keyed.local[shaped], keyed.root[shaped], phenotype), config.iterations, CONVERGED,
                          skin)
    local, root = keyed.local.numpy().copy(), keyed.root.numpy().copy()
    local[shaped], root[shaped] = state.local.numpy(), state.root.numpy()
    return BodyFit(local, root, state.phenotype)


def fit_body(body: SolverBody, points: np.ndarray, face: np.ndarray, barycentric: np.ndarray,
             config: BodyFitConfig = BodyFitConfig()) -> SuitBody:
    """Fit Anny to a take's corners (§5, Chen et al. 2021; see the module's text).

    points (frame, corner, 3) NaN where unobserved; face (corner,) index into ``body.body.faces``; barycentric
    (corner, 2), the corner at (1-u-v) V0 + u V1 + v V2 of its face on the rest body.
    """
    points = np.asarray(points, np.float64)
    face, barycentric = np.asarray(face), np.asarray(barycentric, np.float64)
    _check_places(body, points, face, barycentric)
    counts = np.isfinite(points).all(-1).sum(1)
    fitted = counts >= config.min_corners  # (frame,)
    if not fitted.any():
        raise BodyFitError(f"no frame has {config.min_corners} observed corners (most: {counts.max()}); the body "
                           "cannot be fitted (lower min_corners or check the triangulation)")
    places = lm.Places.of_faces(body.body, face, barycentric)
    weights = lm.place_weights(body, places)
    skin, good = lm.skin_of(body, weights), np.flatnonzero(fitted)
    keys = np.union1d(good[::config.key_stride], good[-1:])
    keyed = _key_frames(body, points[keys], places, skin, config)
    start = _spread(keyed, keys, len(points), np.isin(np.arange(len(points)), keys))
    between = BodyFit(start.local[good], start.root[good], keyed.phenotype)  # E_Theta toward the key frames' poses
    solved = lm.solve_poses(body, places, _terms(points[good], between.local, config), lm.State.of(between),
                            config.iterations, CONVERGED, config.chunk, skin)
    local, root = start.local, start.root
    local[good], root[good] = solved.local.numpy(), solved.root.numpy()
    fit = borrow_poses(BodyFit(local, root, keyed.phenotype), fitted)
    transforms, rest_corners = _rest_frame(body, fit, lm.rest_of(body, keyed.phenotype, (places,)))
    return SuitBody(fit=fit, bone_transforms=transforms, weights=weights, rest=rest_corners, borrowed=~fitted)


def _spread(keyed: BodyFit, keys: np.ndarray, frames: int, known: np.ndarray) -> BodyFit:
    """The key frames' poses interpolated to every frame (``borrow_poses``).  -> BodyFit (frame, ...)"""
    local = np.tile(np.eye(3), (frames, keyed.local.shape[1], 1, 1))
    root = np.zeros((frames, 3))
    local[keys], root[keys] = keyed.local, keyed.root
    return borrow_poses(BodyFit(local, root, keyed.phenotype), known)


def _rest_frame(body: SolverBody, fit: BodyFit, rest: lm.Rest) -> tuple[np.ndarray, np.ndarray]:
    """Bone transforms (frame, bone, 4, 4) and rest corners (corner, 3) in the rest body's frame, feet at z = 0."""
    import torch

    with torch.no_grad():
        vertices, _ = body.rest(torch.from_numpy(np.asarray(fit.phenotype, np.float64)))
        lift = torch.tensor([0.0, 0.0, -float(vertices[:, 2].min())], dtype=torch.float64)
        rots, heads = body.kinematics(torch.from_numpy(fit.local), torch.from_numpy(fit.root), rest.heads)
        shift = heads - (rots @ (rest.heads + lift)[..., None])[..., 0]  # h_k - M_k r_k, r_k lifted
    transforms = np.zeros(rots.shape[:2] + (4, 4))
    transforms[..., :3, :3] = rots.numpy()
    transforms[..., :3, 3] = shift.numpy()
    transforms[..., 3, 3] = 1.0
    return transforms, (rest.points[0] + lift).numpy()

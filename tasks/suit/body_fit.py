"""The body model under the suit's corners (Chen, Park, Macit, Kavan 2021, §5): a skinned body fitted to the
observed corners, for hole filling (tasks/suit/fill) to unpose them into the rest pose and repose the filled ones.

The paper fits STAR, refined per actor; here the body is Anny through the solvers' rig (tasks/shared/solver_body:
``SolverBody``'s rest shape of a phenotype, forward kinematics, skinning weights; the result a ``BodyFit``), fitted
as UUO's inverse kinematics fits markers with known vertices (tasks/uuo/ik, Milef et al. 2024 Eq. 7-8 with zero
marker offset): every corner's place on the rest body is known, a point (face, barycentric) of ``MeshBody.faces``,
so its posed position is a function of the pose and the phenotype, and the fit minimises

    sum_observed ||LBS(corner) - p||^2 / sigma_p^2  +  sum_bones ||theta_b||^2 / sigma_theta^2
                                                    +  ||phenotype - start||^2 / sigma_beta^2

(the second term UUO's E_Theta, each bone's rotation theta_b from an anchor pose, holding bones no corner sees, the
root's rotation free; the third E_beta). A corner is skinned as one point with its own weights, the barycentric
blend of its face's vertices' Anny weights, so that ``fill.skinning_transforms`` / ``unpose`` / ``repose`` apply to
it unchanged; this differs from blending the three skinned vertices by a second-order term (well under a
millimetre; the non-articulated displacements absorb it).

The solver is Levenberg-Marquardt with analytic Jacobians, the normal equations of ``chunk`` frames at once, each
frame damped and stopped on its own (UUO's L-BFGS needs hundreds of evaluations of the whole take, each about half
a second for 150 frames of 1,500 corners: minutes in all). Each bone's rotation is perturbed in the world frame
about its head, which moves the corners it carries by -[a_cb]x delta_b, a_cb = sum_{k below b} w_ck y_ck -
(sum_{k below b} w_ck) h_b (y_ck the corner moved by bone k, h_b the bone's head), and the root's head by a
translation. Three stages:

1. key frames (every ``key_stride``-th fitted frame), each from the rest pose placed rigidly on its observed trunk
   corners (Kabsch), at the start phenotype, E_Theta toward the rest pose; roughly;
2. the phenotype, once per take, jointly with the poses of up to ``shape_frames`` key frames (its six Jacobian
   columns from Anny's rest shape by finite differences, eliminated by a Schur complement);
3. every fitted frame with the phenotype fixed, from its key frames' poses interpolated, E_Theta now toward that
   interpolation (a limb no corner sees in a frame follows its key frames rather than the rest pose).

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

from mocapflow.tasks.shared.kinematics import rigid_fit
from mocapflow.tasks.shared.mesh_body import PHENOTYPE_NAMES, Phenotype, anny_model, part_of_bone
from mocapflow.tasks.shared.solver_body import BodyFit, SolverBody, torch_rodrigues

SHAPE_STEP = 1e-3  # finite-difference step of the rest shape's phenotype Jacobian
SHAPE_REFRESH = 0.05  # the phenotype Jacobian is taken again once the phenotype moved this far
CONVERGED = 1e-3  # relative energy decrease at which an iteration stops the solve
ROUGH = 1e-2  # the same for the key frames' first poses, at the start phenotype (the shape's fit refines them)
GIVE_UP = 1e6  # Levenberg-Marquardt damping at which no step helps any more: the solve stops


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


def _blend(barycentric: np.ndarray) -> np.ndarray:
    """Each corner's weights on its face's three vertices.  -> (corner, 3)"""
    u, v = barycentric.T
    return np.column_stack([1.0 - u - v, u, v])


def corner_weights(body: SolverBody, face: np.ndarray, barycentric: np.ndarray) -> np.ndarray:
    """Skinning weights of each corner: the barycentric blend of its face's vertices' Anny weights.
    face (corner,), barycentric (corner, 2) -> (corner, bone)"""
    vertices = body.body.faces[face]  # (corner, 3)
    w = body.weights.numpy()[vertices] * _blend(barycentric)[..., None]  # (corner, 3, 9)
    out = np.zeros((len(face), body.n_bones))
    rows = np.broadcast_to(np.arange(len(face))[:, None, None], w.shape)
    np.add.at(out, (rows.ravel(), body.indices.numpy()[vertices].ravel()), w.ravel())
    return out


def _below(body: SolverBody) -> np.ndarray:
    """below[k, s]: bone k is seen bone s or under it (turning s moves k).  -> (bone, seen bone) bool"""
    inside = np.eye(body.n_bones, dtype=bool)
    for b in range(1, body.n_bones):  # parents come first
        inside[b] |= inside[body.parents[b]]
    return inside[:, body.seen_bones]


@dataclass(frozen=True)
class _Skin:
    """The corners' skinning, sparse: the bones each corner moves with (padded with zero weights)."""

    bones: object  # (corner, k) long
    weights: object  # (corner, k)
    chains: object  # (corner, k, seen bone): weight where the seen bone carries bone k
    reach: object  # (corner, seen bone): sum of the corner's weights the seen bone carries


def _skin_of(body: SolverBody, weights: np.ndarray) -> _Skin:
    import torch

    k = max(int((weights > 0).sum(1).max()), 1)
    bones = np.argsort(-weights, axis=1)[:, :k]  # (corner, k)
    w = np.take_along_axis(weights, bones, 1)
    chains = w[..., None] * _below(body)[bones]  # (corner, k, seen)
    return _Skin(*(torch.from_numpy(np.ascontiguousarray(x)) for x in (bones, w, chains, chains.sum(1))))


# --- the rest body of a phenotype ------------------------------------------------------------------------------------


@dataclass(frozen=True)
class _Rest:
    corners: object  # (corner, 3) rest positions (torch, Anny's origin)
    heads: object  # (bone, 3) rest bone heads
    d_corners: object | None = None  # (corner, 3, 6) their phenotype derivatives
    d_heads: object | None = None  # (bone, 3, 6)


def _rest_of(body: SolverBody, phenotype: np.ndarray, face: np.ndarray, blend: np.ndarray,
             derivatives: bool = False) -> _Rest:
    """Rest corners and bone heads of a phenotype, with their derivatives (forward differences) on request."""
    import torch

    steps = np.where(phenotype + SHAPE_STEP <= 1.0, SHAPE_STEP, -SHAPE_STEP)
    batch = np.vstack([phenotype] + ([phenotype + np.diag(steps)] if derivatives else []))  # (1 or 7, 6)
    model = anny_model()
    with torch.no_grad():  # SolverBody.rest for a batch of phenotypes (one call of Anny is much cheaper than 7)
        out = model(phenotype_kwargs={name: torch.from_numpy(batch[:, i]) for i, name in enumerate(PHENOTYPE_NAMES)})
        vertices = out["rest_vertices"] @ body.facing.T  # (batch, vertex, 3)
        heads = out["rest_bone_poses"][:, :, :3, 3] @ body.facing.T  # (batch, bone, 3)
    corners = (vertices[:, body.body.faces[face]] * torch.from_numpy(blend)[..., None]).sum(2)  # (batch, corner, 3)
    if not derivatives:
        return _Rest(corners[0], heads[0])
    scale = torch.from_numpy(steps)
    return _Rest(corners[0], heads[0], ((corners[1:] - corners[0]) / scale[:, None, None]).permute(1, 2, 0),
                 ((heads[1:] - heads[0]) / scale[:, None, None]).permute(1, 2, 0))


# --- posing and its derivatives --------------------------------------------------------------------------------------


@dataclass
class _State:
    local: object  # (frame, bone, 3, 3)
    root: object  # (frame, 3)
    phenotype: np.ndarray  # (6,)
    anchor: object  # (frame, seen bone but the root, 3, 3): the local rotations E_Theta pulls toward


@dataclass
class _Posed:
    rots: object  # (frame, bone, 3, 3)
    heads: object  # (frame, bone, 3)
    points: object  # (frame, corner, 3) posed corners
    moved: object  # (frame, corner, k, 3): y_ck, each corner moved by each of its bones


def _pose(body: SolverBody, state: _State, rest: _Rest, skin: _Skin) -> _Posed:
    """Posed corners (linear blend skinning)."""
    rots, heads = body.kinematics(state.local, state.root, rest.heads)
    offset = rest.corners[:, None] - rest.heads[skin.bones]  # (corner, k, 3)
    moved = (rots[:, skin.bones] @ offset[..., None])[..., 0] + heads[:, skin.bones]  # (frame, corner, k, 3)
    return _Posed(rots, heads, (skin.weights[..., None] * moved).sum(2), moved)


def _levers(body: SolverBody, posed: _Posed, skin: _Skin, mask):
    """a_cb of the module's text, zero on unobserved corners (mask (frame, corner)).  -> (frame, corner, seen, 3)"""
    import torch

    seen_heads = posed.heads[:, torch.from_numpy(np.flatnonzero(body.seen_bones))]  # (frame, seen, 3)
    lever = torch.einsum("cks,fcka->fcsa", skin.chains, posed.moved) - skin.reach[..., None] * seen_heads[:, None]
    return lever * mask[..., None, None]


def _shape_jacobian(body: SolverBody, state: _State, rest: _Rest, skin: _Skin, posed: _Posed):
    """d corner / d phenotype: sum_k w_ck (M_k (dx_c - dr_k) + dh_k).  -> (frame, corner, 3, 6)"""
    import torch

    frames = state.root.shape[0]
    dh = torch.stack([body.kinematics(state.local, torch.zeros(frames, 3, dtype=torch.float64),
                                      rest.d_heads[..., i])[1] for i in range(6)], -1)  # (frame, bone, 3, 6)
    offset = rest.d_corners[:, None] - rest.d_heads[skin.bones]  # (corner, k, 3, 6)
    moved = posed.rots[:, skin.bones] @ offset + dh[:, skin.bones]  # (frame, corner, k, 3, 6)
    return (skin.weights[..., None, None] * moved).sum(2)


def _rotvecs(local):
    """Rotation vectors of rotation matrices (torch, no gradient).  (..., 3, 3) -> (..., 3)"""
    import torch

    flat = local.reshape(-1, 3, 3).numpy()
    return torch.from_numpy(Rotation.from_matrix(flat).as_rotvec().reshape(local.shape[:-1]))


def _energies(body: SolverBody, state: _State, posed: _Posed, target, mask, config: BodyFitConfig):
    """Each frame's energy (the module's text, without E_beta).  -> (frame,)"""
    data = (((posed.points - target) ** 2).sum(-1) * mask).sum(1) / config.point_sigma_m ** 2  # Eq. (8), Milef et
    # al. 2024, zero marker offset: the corner is on the skin
    prior = (_rotvecs(_from_anchor(body, state)) ** 2).sum((1, 2)) / config.pose_sigma_rad ** 2  # E_Theta, Eq. (5)
    return data + prior


def _prior_bones(body: SolverBody):
    import torch

    return torch.from_numpy(np.flatnonzero(body.seen_bones)[1:])  # every seen bone but the root


def _from_anchor(body: SolverBody, state: _State):
    """Each prior bone's local rotation relative to the anchor's.  -> (frame, seen - 1, 3, 3)"""
    return state.anchor.transpose(-1, -2) @ state.local[:, _prior_bones(body)]


# --- normal equations ------------------------------------------------------------------------------------------------


_LEVI = np.zeros((3, 3, 3))
_LEVI[0, 1, 2] = _LEVI[1, 2, 0] = _LEVI[2, 0, 1] = 1.0
_LEVI[0, 2, 1] = _LEVI[2, 1, 0] = _LEVI[1, 0, 2] = -1.0


def _normal_equations(body: SolverBody, state: _State, posed: _Posed, lever, target, mask, config: BodyFitConfig):
    """J^T J and J^T r of every frame's pose parameters (seen bones' world rotations, then the root's head), the
    corners scaled by 1 / sigma_p and E_Theta added.  -> (frame, P, P), (frame, P)"""
    import torch

    frames, _, seen, _ = lever.shape
    a = lever  # zero on unobserved corners
    residual = (posed.points - target) * mask[..., None]
    gram = a.reshape(frames, -1, seen * 3).transpose(1, 2) @ a.reshape(frames, -1, seen * 3)
    gram = gram.reshape(frames, seen, 3, seen, 3)  # G[j, alpha, l, beta] = sum_c a_cj,alpha a_cl,beta
    trace = gram.diagonal(dim1=2, dim2=4).sum(-1)  # (frame, seen, seen)
    eye = torch.eye(3, dtype=torch.float64)
    rot = trace[:, :, None, :, None] * eye[None, None, :, None, :] - gram.transpose(2, 4)  # [a_j]x^T [a_l]x summed
    p = 3 * seen + 3
    lhs = torch.zeros(frames, p, p, dtype=torch.float64)
    lhs[:, :3 * seen, :3 * seen] = rot.reshape(frames, 3 * seen, 3 * seen)
    cross = torch.einsum("gab,fsa->fsgb", torch.from_numpy(_LEVI), a.sum(1))  # [sum_c a_cj]x  (frame, seen, 3, 3)
    lhs[:, :3 * seen, 3 * seen:] = cross.reshape(frames, 3 * seen, 3)
    lhs[:, 3 * seen:, :3 * seen] = cross.reshape(frames, 3 * seen, 3).transpose(1, 2)
    lhs[:, 3 * seen:, 3 * seen:] = mask.sum(1)[:, None, None] * eye
    moments = torch.einsum("fcsa,fcb->fsab", a, residual)  # sum_c a_cj r_c^T
    rhs = torch.cat([torch.einsum("gab,fsab->fsg", torch.from_numpy(_LEVI), moments).reshape(frames, -1),
                     residual.sum(1)], 1)  # J^T r: sum_c a_cj x r_c, sum_c r_c
    lhs, rhs = lhs / config.point_sigma_m ** 2, rhs / config.point_sigma_m ** 2
    return _add_pose_prior(body, state, posed, lhs, rhs, config)


def _add_pose_prior(body: SolverBody, state: _State, posed: _Posed, lhs, rhs, config: BodyFitConfig):
    """E_Theta, linearised: ||rho_b + A_b^T M_parent^T delta_b||^2 / sigma^2 for every seen bone but the root,
    rho_b the rotation vector of its local rotation relative to the anchor's A_b."""
    import torch

    seen = np.flatnonzero(body.seen_bones)
    kappa = 1.0 / config.pose_sigma_rad ** 2
    rho = _rotvecs(_from_anchor(body, state))  # (frame, seen - 1, 3)
    parent_rots = posed.rots[:, torch.from_numpy(body.parents[seen[1:]])]  # (frame, seen - 1, 3, 3)
    index = torch.arange(3, 3 * len(seen))
    lhs[:, index, index] += kappa
    rhs[:, 3:3 * len(seen)] += kappa * (parent_rots @ state.anchor @ rho[..., None])[..., 0].reshape(len(rho), -1)
    return lhs, rhs


def _shape_blocks(jac, posed: _Posed, lever, target, mask, config: BodyFitConfig):
    """The phenotype's rows of the normal equations.  jac (frame, corner, 3, 6) -> J_p^T J_phi (frame, P, 6),
    J_phi^T J_phi (frame, 6, 6), J_phi^T r (frame, 6)"""
    import torch

    frames, _, seen, _ = lever.shape
    masked = jac * mask[..., None, None]
    residual = (posed.points - target) * mask[..., None]
    lever_jac = torch.einsum("fcsa,fcbm->fsabm", lever, masked)  # (frame, seen, 3, 3, 6)
    rot = torch.einsum("gab,fsabm->fsgm", torch.from_numpy(_LEVI), lever_jac)  # sum_c [a_cj]x J_c
    cross = torch.cat([rot.reshape(frames, 3 * seen, 6), masked.sum(1)], 1)
    scale = config.point_sigma_m ** 2
    return (cross / scale, torch.einsum("fcam,fcan->fmn", masked, jac) / scale,
            torch.einsum("fcam,fca->fm", masked, residual) / scale)


# --- steps -----------------------------------------------------------------------------------------------------------


def _apply(body: SolverBody, state: _State, posed: _Posed, step) -> _State:
    """Turn each seen bone by its world rotation about its head and move the root: L_b <- exp(M_parent^T delta_b) L_b
    (the root's: exp(delta) L_root).  step (frame, P)"""
    import torch

    seen = np.flatnonzero(body.seen_bones)
    frames = step.shape[0]
    delta = step[:, :3 * len(seen)].reshape(frames, len(seen), 3)
    local = state.local.clone()
    parents = np.maximum(body.parents[seen], 0)
    frame_delta = (posed.rots[:, torch.from_numpy(parents)].transpose(-1, -2) @ delta[..., None])[..., 0]
    frame_delta[:, 0] = delta[:, 0]  # the root: its local rotation is its world one
    local[:, torch.from_numpy(seen)] = torch_rodrigues(frame_delta) @ state.local[:, torch.from_numpy(seen)]
    return _State(local, state.root + step[:, 3 * len(seen):], state.phenotype, state.anchor)


def _damped(lhs, damping):
    import torch

    diagonal = lhs.diagonal(dim1=1, dim2=2)
    return lhs + torch.diag_embed(damping[:, None] * diagonal + 1e-9)


def _solve_poses(body: SolverBody, state: _State, rest: _Rest, skin: _Skin, target, mask, config: BodyFitConfig,
                 tolerance: float = CONVERGED) -> _State:
    """Levenberg-Marquardt on every frame's pose, the phenotype fixed; each frame damped on its own and left out
    once a step changes its energy by less than ``tolerance`` (relative) or no step helps."""
    import torch

    posed = _pose(body, state, rest, skin)
    energy = _energies(body, state, posed, target, mask, config)
    damping = torch.full((state.root.shape[0],), 1e-3, dtype=torch.float64)
    active = torch.ones(state.root.shape[0], dtype=torch.bool)
    for _ in range(config.iterations):
        idx = torch.nonzero(active)[:, 0]
        sub, sub_posed = (state, posed) if active.all() else (_frames(state, idx), _frames(posed, idx))
        lever = _levers(body, sub_posed, skin, mask[idx])
        lhs, rhs = _normal_equations(body, sub, sub_posed, lever, target[idx], mask[idx], config)
        trial = _apply(body, sub, sub_posed, torch.linalg.solve(_damped(lhs, damping[idx]), -rhs))
        trial_posed = _pose(body, trial, rest, skin)
        trial_energy = _energies(body, trial, trial_posed, target[idx], mask[idx], config)
        better = trial_energy < energy[idx]
        gain = (energy[idx] - trial_energy) / energy[idx].clamp_min(1e-30)
        _store(state, idx[better], _frames(trial, better))
        _store(posed, idx[better], _frames(trial_posed, better))
        energy[idx[better]] = trial_energy[better]
        damping[idx] = torch.where(better, damping[idx] / 3.0, damping[idx] * 4.0)
        active[idx[(gain.abs() < tolerance) | (damping[idx] > GIVE_UP)]] = False
        if not active.any():
            break
    return state


def _frames(items, idx):
    """A _State's or _Posed's chosen frames (index or mask)."""
    kind = type(items)
    return kind(**{k: v if isinstance(v, np.ndarray) else v[idx] for k, v in vars(items).items()})


def _store(items, idx, new) -> None:
    """Write chosen frames of a _State or _Posed in place."""
    for k, v in vars(items).items():
        if not isinstance(v, np.ndarray):
            v[idx] = getattr(new, k)


def _solve_shape(body: SolverBody, state: _State, face: np.ndarray, blend: np.ndarray, skin: _Skin, target, mask,
                 config: BodyFitConfig) -> _State:
    """Levenberg-Marquardt on the phenotype and the poses of a few frames together (Schur complement on the
    phenotype), one damping for all. The rest shape's phenotype derivatives are evaluated again only once the
    phenotype has moved SHAPE_REFRESH from where they were taken (Anny's rest shape is piecewise linear in it), or
    when a step on them fails."""

    rest = _rest_of(body, state.phenotype, face, blend, derivatives=True)
    derived_at = state.phenotype
    posed = _pose(body, state, rest, skin)
    total = _total(body, state, posed, target, mask, config)
    damping = 1e-3
    for _ in range(config.iterations):
        step = _shape_step(body, state, rest, skin, posed, target, mask, damping, config)
        trial = _apply(body, state, posed, step[0])
        trial.phenotype = np.clip(state.phenotype + step[1].numpy(), 0.0, 1.0)
        refresh = np.abs(trial.phenotype - derived_at).max() > SHAPE_REFRESH
        trial_rest = _rest_of(body, trial.phenotype, face, blend, derivatives=refresh)
        if not refresh:
            trial_rest = _Rest(trial_rest.corners, trial_rest.heads, rest.d_corners, rest.d_heads)
        trial_posed = _pose(body, trial, trial_rest, skin)
        trial_total = _total(body, trial, trial_posed, target, mask, config)
        gain = (total - trial_total) / total
        if trial_total < total:
            state, rest, posed, total, damping = trial, trial_rest, trial_posed, trial_total, damping / 3.0
            derived_at = trial.phenotype if refresh else derived_at
        elif (derived_at != state.phenotype).any():  # a step failed on old derivatives: take them here first
            rest, derived_at = _rest_of(body, state.phenotype, face, blend, derivatives=True), state.phenotype
            continue
        else:
            damping *= 4.0
        if abs(gain) < CONVERGED or damping > GIVE_UP:
            break
    return state


def _shape_step(body: SolverBody, state: _State, rest: _Rest, skin: _Skin, posed: _Posed, target, mask,
                damping: float, config: BodyFitConfig):
    """One damped Gauss-Newton step of poses and phenotype: the phenotype's through the Schur complement
    H_phi,phi - sum_f H_phi,p H_pp^-1 H_p,phi, then each frame's pose.  -> (frame, P), (6,)"""
    import torch

    lever = _levers(body, posed, skin, mask)
    lhs, rhs = _normal_equations(body, state, posed, lever, target, mask, config)
    cross, shape_lhs, shape_rhs = _shape_blocks(_shape_jacobian(body, state, rest, skin, posed), posed, lever,
                                                target, mask, config)
    shape_lhs = shape_lhs.sum(0) + torch.eye(6, dtype=torch.float64) / config.shape_sigma ** 2  # E_beta
    shape_rhs = shape_rhs.sum(0) + torch.from_numpy(state.phenotype - _phenotype(config.start)) \
        / config.shape_sigma ** 2
    damped = _damped(lhs, torch.full((lhs.shape[0],), damping, dtype=torch.float64))
    solved = torch.linalg.solve(damped, torch.cat([cross, rhs[..., None]], -1))  # H_pp^-1 [H_p,phi, g_p]
    schur = shape_lhs * (1 + damping) - (cross.transpose(1, 2) @ solved[..., :6]).sum(0)
    d_shape = torch.linalg.solve(schur, -shape_rhs + (cross.transpose(1, 2) @ solved[..., 6:]).sum(0)[:, 0])
    return -solved[..., 6] - solved[..., :6] @ d_shape, d_shape


def _total(body: SolverBody, state: _State, posed: _Posed, target, mask, config: BodyFitConfig) -> float:
    shape = ((state.phenotype - _phenotype(config.start)) ** 2).sum() / config.shape_sigma ** 2  # E_beta, Eq. (2)
    return float(_energies(body, state, posed, target, mask, config).sum()) + float(shape)


# --- the take --------------------------------------------------------------------------------------------------------


def _phenotype(p: Phenotype) -> np.ndarray:
    return np.array([getattr(p, name) for name in PHENOTYPE_NAMES], np.float64)


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


def _start(body: SolverBody, points: np.ndarray, rest: _Rest, trunk: np.ndarray, phenotype: np.ndarray) -> _State:
    import torch

    rotation, root = placed_rest_pose(points, rest.corners.numpy(), rest.heads[0].numpy(), trunk)
    local = np.tile(np.eye(3), (len(points), body.n_bones, 1, 1))
    local[:, 0] = rotation
    rest_pose = torch.from_numpy(local[:, _prior_bones(body)])  # E_Theta toward the rest pose
    return _State(torch.from_numpy(local), torch.from_numpy(root), phenotype, rest_pose)


def _targets(points: np.ndarray):
    import torch

    seen = np.isfinite(points).all(-1)
    return torch.from_numpy(np.where(seen[..., None], points, 0.0)), torch.from_numpy(seen.astype(np.float64))


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


def _trunk(body: SolverBody, face: np.ndarray, parts: tuple[str, ...]) -> np.ndarray:
    part = np.array([part_of_bone(n) for n in body.body.bone_names])
    return np.isin(part[body.body.vertex_bone[body.body.faces[face, 0]]], parts)


def _poses(body: SolverBody, points: np.ndarray, start: _State, rest: _Rest, skin: _Skin, config: BodyFitConfig,
           tolerance: float = CONVERGED) -> _State:
    """Every given frame's pose, ``chunk`` frames at a time, the phenotype fixed.  points (frame, corner, 3)"""
    import torch

    parts = []
    for s in range(0, len(points), config.chunk):
        part = slice(s, s + config.chunk)
        parts.append(_solve_poses(body, _frames(start, part), rest, skin, *_targets(points[part]), config,
                                  tolerance))
    return _State(torch.cat([p.local for p in parts]), torch.cat([p.root for p in parts]), start.phenotype,
                  torch.cat([p.anchor for p in parts]))


def _key_frames(body: SolverBody, points: np.ndarray, face: np.ndarray, blend: np.ndarray, skin: _Skin,
                config: BodyFitConfig) -> _State:
    """The key frames posed from the rest pose at the start phenotype (roughly), then the phenotype fitted with the
    poses of up to ``shape_frames`` of them.  points (key frame, corner, 3)"""
    import torch

    phenotype = _phenotype(config.start)
    rest = _rest_of(body, phenotype, face, blend)
    keyed = _poses(body, points, _start(body, points, rest, _trunk(body, face, config.trunk), phenotype), rest, skin,
                   config, ROUGH)
    shaped = torch.from_numpy(_evenly(np.arange(len(points)), config.shape_frames))
    state = _solve_shape(body, _frames(keyed, shaped), face, blend, skin, *_targets(points[shaped.numpy()]), config)
    _store(keyed, shaped, state)
    keyed.phenotype = state.phenotype
    return keyed


def fit_body(body: SolverBody, points: np.ndarray, face: np.ndarray, barycentric: np.ndarray,
             config: BodyFitConfig = BodyFitConfig()) -> SuitBody:
    """Fit Anny to a take's corners (§5, Chen et al. 2021; see the module's text).

    points (frame, corner, 3) NaN where unobserved; face (corner,) index into ``body.body.faces``; barycentric
    (corner, 2), the corner at (1-u-v) V0 + u V1 + v V2 of its face on the rest body.
    """
    import torch

    points = np.asarray(points, np.float64)
    face, barycentric = np.asarray(face), np.asarray(barycentric, np.float64)
    _check_places(body, points, face, barycentric)
    counts = np.isfinite(points).all(-1).sum(1)
    fitted = counts >= config.min_corners  # (frame,)
    if not fitted.any():
        raise BodyFitError(f"no frame has {config.min_corners} observed corners (most: {counts.max()}); the body "
                           "cannot be fitted (lower min_corners or check the triangulation)")
    blend, weights = _blend(barycentric), corner_weights(body, face, barycentric)
    skin, good = _skin_of(body, weights), np.flatnonzero(fitted)
    keys = np.union1d(good[::config.key_stride], good[-1:])
    with torch.no_grad():
        keyed = _key_frames(body, points[keys], face, blend, skin, config)
        phenotype = keyed.phenotype
        rest = _rest_of(body, phenotype, face, blend)
        start = _spread(keyed, keys, len(points), np.isin(np.arange(len(points)), keys))
        between = torch.from_numpy(start.local[good])  # E_Theta toward the key frames' poses, interpolated
        solved = _poses(body, points[good], _State(between, torch.from_numpy(start.root[good]), phenotype,
                                                   between[:, _prior_bones(body)].clone()), rest, skin, config)
    local, root = start.local, start.root
    local[good], root[good] = solved.local.numpy(), solved.root.numpy()
    fit = borrow_poses(BodyFit(local, root, phenotype), fitted)
    transforms, rest_corners = _rest_frame(body, fit, rest)
    return SuitBody(fit=fit, bone_transforms=transforms, weights=weights, rest=rest_corners, borrowed=~fitted)


def _spread(keyed: _State, keys: np.ndarray, frames: int, known: np.ndarray) -> BodyFit:
    """The key frames' poses interpolated to every frame (``borrow_poses``).  -> BodyFit (frame, ...)"""
    local = np.tile(np.eye(3), (frames, keyed.local.shape[1], 1, 1))
    root = np.zeros((frames, 3))
    local[keys], root[keys] = keyed.local.numpy(), keyed.root.numpy()
    return borrow_poses(BodyFit(local, root, keyed.phenotype), known)


def _rest_frame(body: SolverBody, fit: BodyFit, rest: _Rest) -> tuple[np.ndarray, np.ndarray]:
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
    return transforms, (rest.corners + lift).numpy()

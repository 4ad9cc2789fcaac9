"""The house's body fitter: Anny's rig (tasks/shared/solver_body) fitted to points at known places on its skin by
Levenberg-Marquardt with analytic Jacobians. The checkerboard suit fits it to its corners (Chen et al. 2021, §5),
UUO to the markers' closest skin points (Milef et al. 2024, §3.5.2, Eq. 1) and to their correspondences (§3.5.4,
Eq. 7-8).

A place is a point of the rest mesh, a blend of three vertices (a face and its barycentric coordinates, or one
vertex three times), skinned as one point with its own weights, the same blend of its vertices' Anny weights. The
energy, every term but the points' optional:

    E = sum_f sum_n w_fn (|v_fn - p_fn| - delta)^2                 the points: v the place's skinned position, p the
                                                                   observation, delta the marker's offset (Eq. 8)
      + sum_f sum_b k_fb psi(A_fb^T L_fb)                           E_Theta, Eq. (5): each held bone's local rotation
                                                                   L from its anchor A; psi = |log R|^2 ("angle") or
                                                                   2 (1 - cos angle) = 3 - tr R ("chord")
      + w_floor sum_f sum_v max(0, h - z_fv)^2                      the skin kept above the floor z = h
      + w_shape |phenotype - phenotype_0|^2                         E_beta, Eq. (2)

Parameters: per frame each seen bone's rotation, perturbed in the world frame about its head (L_b <- exp(M_parent^T
delta_b) L_b), which moves a point it carries by -[a_nb]x delta_b, a_nb = sum_{k below b} w_nk y_nk - (sum_{k below
b} w_nk) h_b (y_nk the place moved by bone k, h_b the bone's head), and the root's head by a translation; per take
the phenotype, through a Schur complement, its Jacobian from Anny's rest shape by forward differences.

Gauss-Newton with exact gradients: a point's residual is the vector (d - delta) u, u = (v - p) / d, whose norm is
the term's and whose Jacobian is taken as v's (the gradient exact; the Hessian's curvature of u left out, positive
where d > delta); E_Theta "chord" has the gradient vee(Q - Q^T) in Q = A^T L and the Hessian 2 I of its small
angles, "angle" the linearised rotation vector (the suit's form). A solve's fixed point is therefore a stationary
point of E itself: where an L-BFGS solve of the same energy converges, both land on the same body.

Two solvers: ``solve_poses`` (the phenotype fixed; each frame damped and stopped on its own, ``chunk`` frames at a
time) and ``solve_take`` (the phenotype with every frame's pose, one damping). Tensors are float64 torch, no
gradient; no IO.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from scipy.spatial.transform import Rotation

from mocapflow.tasks.shared.mesh_body import PHENOTYPE_NAMES, MeshBody, anny_model
from mocapflow.tasks.shared.solver_body import BodyFit, SolverBody, torch_rodrigues

SHAPE_STEP = 1e-3  # finite-difference step of the rest shape's phenotype Jacobian
SHAPE_REFRESH = 0.05  # the phenotype Jacobian is taken again once the phenotype moved this far
GIVE_UP = 1e6  # Levenberg-Marquardt damping at which no step helps any more: the solve stops
FORMS = ("angle", "chord")


class FitError(ValueError):
    """Places, points or terms the body fitter cannot use."""


@dataclass(frozen=True)
class Places:
    """Points of the rest mesh: each a blend of three vertices."""

    vertices: np.ndarray  # (place, 3) vertex indices
    blend: np.ndarray  # (place, 3) their weights, summing to 1

    @classmethod
    def of_vertices(cls, index) -> Places:
        index = np.asarray(index, np.int64)
        return cls(np.repeat(index[:, None], 3, 1), np.tile([1.0, 0.0, 0.0], (len(index), 1)))

    @classmethod
    def of_faces(cls, body: MeshBody, face, barycentric) -> Places:
        """Face (place,) and barycentric (u, v) (place, 2): the point (1-u-v) V0 + u V1 + v V2."""
        u, v = np.asarray(barycentric, np.float64).T
        return cls(body.faces[np.asarray(face)], np.column_stack([1.0 - u - v, u, v]))


@dataclass(frozen=True)
class Points:
    """Observed points and the places they belong at."""

    place: np.ndarray  # (n,) the same places every frame, or (frame, n): index into the fit's Places
    target: np.ndarray  # (frame, n, 3) metres; any value where the weight is 0
    weight: np.ndarray  # (frame, n) w_fn, 0 where unobserved or left out
    offset: float = 0.0  # delta: the observation's distance from the skin (a marker's centre above it)


@dataclass(frozen=True)
class PosePrior:
    """E_Theta toward anchor rotations."""

    anchor: np.ndarray  # (frame, bone, 3, 3) local rotations
    weight: np.ndarray  # (frame,) k_f, each held bone's weight in that frame
    root: bool = False  # the root's rotation held too (else free)
    form: str = "angle"  # psi: "angle" |log R|^2 or "chord" 3 - tr R


@dataclass(frozen=True)
class FloorTerm:
    height: float  # h (m)
    places: Places  # the skin points kept above it
    weight: float  # w_floor


@dataclass(frozen=True)
class Terms:
    points: Points
    prior: PosePrior
    floor: FloorTerm | None = None
    shape_anchor: np.ndarray | None = None  # phenotype_0 (6,)
    shape_weight: float = 0.0  # w_shape


def check_terms(terms: Terms, places: Places, frames: int) -> None:
    p = terms.points
    if p.target.shape[:1] != (frames,) or p.target.shape[2:] != (3,) or p.weight.shape != p.target.shape[:2] \
            or p.place.shape not in ((p.target.shape[1],), p.target.shape[:2]):
        raise FitError(f"points need target (frame, n, 3), weight (frame, n) and place (n,) or (frame, n) for "
                       f"{frames} frames; got {p.target.shape}, {p.weight.shape} and {p.place.shape}")
    if p.place.size and (p.place.min() < 0 or p.place.max() >= len(places.vertices)):
        raise FitError(f"point places index {len(places.vertices)} places; got [{p.place.min()}, {p.place.max()}]")
    if (p.weight < 0).any() or not np.isfinite(p.weight).all() or not np.isfinite(p.target[p.weight > 0]).all():
        raise FitError("point weights must be finite and >= 0, and every weighted target finite (weight 0 where "
                       "unobserved)")
    if terms.prior.form not in FORMS or terms.prior.weight.shape != (frames,):
        raise FitError(f"the pose prior's form is one of {FORMS} with a weight per frame ({frames}); got "
                       f"{terms.prior.form!r} and {terms.prior.weight.shape}")


# --- places on the body ----------------------------------------------------------------------------------------------


def place_weights(body: SolverBody, places: Places) -> np.ndarray:
    """Skinning weights of each place: the blend of its vertices' Anny weights.  -> (place, bone)"""
    return sum(places.blend[:, j, None] * body.dense_weights(places.vertices[:, j]).numpy() for j in range(3))


def _below(body: SolverBody) -> np.ndarray:
    """below[k, s]: bone k is seen bone s or under it (turning s moves k).  -> (bone, seen bone) bool"""
    inside = np.eye(body.n_bones, dtype=bool)
    for b in range(1, body.n_bones):  # parents come first
        inside[b] |= inside[body.parents[b]]
    return inside[:, body.seen_bones]


@dataclass(frozen=True)
class Skin:
    """The places' skinning, sparse: the bones each place moves with (padded with zero weights)."""

    bones: object  # (place, k) long
    weights: object  # (place, k)
    chains: object  # (place, k, seen bone): weight where the seen bone carries bone k
    reach: object  # (place, seen bone): sum of the place's weights the seen bone carries


def skin_of(body: SolverBody, weights: np.ndarray) -> Skin:
    import torch

    k = max(int((weights > 0).sum(1).max(initial=0)), 1)
    bones = np.argsort(-weights, axis=1)[:, :k]  # (place, k)
    w = np.take_along_axis(weights, bones, 1)
    chains = w[..., None] * _below(body)[bones]  # (place, k, seen)
    return Skin(*(torch.from_numpy(np.ascontiguousarray(x)) for x in (bones, w, chains, chains.sum(1))))


def _gather(skin: Skin, place):
    """The skin rows of ``place`` (n,) or (frame, n)."""
    return Skin(skin.bones[place], skin.weights[place], skin.chains[place], skin.reach[place])


# --- the rest body of a phenotype ------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Rest:
    heads: object  # (bone, 3) rest bone heads
    points: tuple  # per Places given: (place, 3) rest positions
    d_heads: object | None = None  # (bone, 3, 6) phenotype derivatives
    d_points: tuple | None = None  # per Places: (place, 3, 6)


def rest_of(body: SolverBody, phenotype: np.ndarray, places: tuple[Places, ...], derivatives: bool = False) -> Rest:
    """Rest places and bone heads of a phenotype (studio axes, Anny's origin), with their derivatives (forward
    differences) on request."""
    import torch

    steps = np.where(phenotype + SHAPE_STEP <= 1.0, SHAPE_STEP, -SHAPE_STEP)
    batch = np.vstack([phenotype] + ([phenotype + np.diag(steps)] if derivatives else []))  # (1 or 7, 6)
    with torch.no_grad():  # one call of Anny for a batch of phenotypes is much cheaper than 7
        out = anny_model()(phenotype_kwargs={name: torch.from_numpy(batch[:, i])
                                             for i, name in enumerate(PHENOTYPE_NAMES)})
        vertices = out["rest_vertices"] @ body.facing.T  # (batch, vertex, 3)
        heads = out["rest_bone_poses"][:, :, :3, 3] @ body.facing.T  # (batch, bone, 3)
    points = [(vertices[:, p.vertices] * torch.from_numpy(p.blend)[..., None]).sum(2) for p in places]
    if not derivatives:
        return Rest(heads[0], tuple(x[0] for x in points))
    scale = torch.from_numpy(steps)

    def derivative(x):
        return ((x[1:] - x[0]) / scale[:, None, None]).permute(1, 2, 0)

    return Rest(heads[0], tuple(x[0] for x in points), derivative(heads), tuple(derivative(x) for x in points))


# --- the state and its posing ----------------------------------------------------------------------------------------


@dataclass
class State:
    local: object  # (frame, bone, 3, 3) local rotations (the root's: world)
    root: object  # (frame, 3) the root's head
    phenotype: np.ndarray  # (6,)

    @classmethod
    def of(cls, fit: BodyFit) -> State:
        import torch

        return cls(torch.from_numpy(np.array(fit.local, np.float64)), torch.from_numpy(np.array(fit.root, np.float64)),
                   np.array(fit.phenotype, np.float64))

    def result(self) -> BodyFit:
        return BodyFit(self.local.numpy().copy(), self.root.numpy().copy(), self.phenotype.copy())


@dataclass
class _Frames:
    """A problem's per-frame tensors (a chunk's or a subset's)."""

    place: object  # (n,) or (frame, n)
    target: object  # (frame, n, 3)
    weight: object  # (frame, n)
    anchor: object  # (frame, held bone, 3, 3)
    prior: object  # (frame,)

    def take(self, idx) -> _Frames:
        return _Frames(self.place if self.place.dim() == 1 else self.place[idx], self.target[idx], self.weight[idx],
                       self.anchor[idx], self.prior[idx])


@dataclass(frozen=True)
class _Problem:
    body: SolverBody
    places: Places
    skin: Skin
    floor_skin: Skin | None
    dense: object  # (place, bone) skinning weights
    floor_dense: object | None
    terms: Terms
    held: object  # (held bone,) bones of E_Theta
    held_in_seen: object  # (held bone,) their index among the seen bones

    def rest(self, phenotype: np.ndarray, derivatives: bool = False) -> Rest:
        floor = (self.terms.floor.places,) if self.terms.floor is not None else ()
        return rest_of(self.body, phenotype, (self.places,) + floor, derivatives)


def _problem(body: SolverBody, places: Places, terms: Terms, skin: Skin | None = None) -> _Problem:
    import torch

    seen = np.flatnonzero(body.seen_bones)
    held = seen if terms.prior.root else seen[1:]
    weights = place_weights(body, places)
    floor = place_weights(body, terms.floor.places) if terms.floor is not None else None
    return _Problem(body, places, skin if skin is not None else skin_of(body, weights),
                    skin_of(body, floor) if floor is not None else None, torch.from_numpy(weights),
                    torch.from_numpy(floor) if floor is not None else None,
                    terms, torch.from_numpy(held), torch.from_numpy(np.searchsorted(seen, held)))


def _frames_of(problem: _Problem) -> _Frames:
    import torch

    p, prior = problem.terms.points, problem.terms.prior
    return _Frames(torch.from_numpy(np.asarray(p.place, np.int64)),
                   torch.from_numpy(np.where(p.weight[..., None] > 0, p.target, 0.0).astype(np.float64)),
                   torch.from_numpy(np.asarray(p.weight, np.float64)),
                   torch.from_numpy(np.asarray(prior.anchor, np.float64)[:, problem.held.numpy()]),
                   torch.from_numpy(np.asarray(prior.weight, np.float64)))


@dataclass
class _Posed:
    rots: object  # (frame, bone, 3, 3)
    heads: object  # (frame, bone, 3)
    points: object  # (frame, n, 3) posed places of the points
    moved: object  # (frame, n, k, 3): y_nk, each place moved by each of its bones
    floor: object | None  # (frame, v, 3) posed floor places


def _skinned(rots, heads, rest_points, rest_heads, skin: Skin, place):
    """Posed places of ``place`` (n,) or (frame, n) (linear blend skinning) and each moved by each of its bones."""
    bones, weights, points = skin.bones[place], skin.weights[place], rest_points[place]
    offset = points[..., None, :] - rest_heads[bones]  # (..., n, k, 3)
    if bones.dim() == 2:
        moved = (rots[:, bones] @ offset[..., None])[..., 0] + heads[:, bones]  # (frame, n, k, 3)
    else:
        import torch

        f = torch.arange(rots.shape[0])[:, None, None]
        moved = (rots[f, bones] @ offset[..., None])[..., 0] + heads[f, bones]
    return (weights[..., None] * moved).sum(-2), moved


def _pose(problem: _Problem, state: State, rest: Rest, frames: _Frames) -> _Posed:
    rots, heads = problem.body.kinematics(state.local, state.root, rest.heads)
    points, moved = _skinned(rots, heads, rest.points[0], rest.heads, problem.skin, frames.place)
    floor = None
    if problem.floor_skin is not None:
        floor = problem.body.skin_dense(rots, heads, rest.points[1], rest.heads, problem.floor_dense)
    return _Posed(rots, heads, points, moved, floor)


def _levers(problem: _Problem, heads, moved, skin: Skin):
    """a_nb of the module's text.  moved (frame, n, k, 3); skin gathered for n -> (frame, n, seen, 3)"""
    import torch

    seen_heads = heads[:, torch.from_numpy(np.flatnonzero(problem.body.seen_bones))]  # (frame, seen, 3)
    spec = "nks,fnka->fnsa" if skin.chains.dim() == 3 else "fnks,fnka->fnsa"
    return torch.einsum(spec, skin.chains, moved) - skin.reach[..., None] * seen_heads[:, None]


def _residuals(problem: _Problem, posed: _Posed, frames: _Frames):
    """The points' residual vectors (d - delta) u.  -> (frame, n, 3)"""
    diff = posed.points - frames.target
    offset = problem.terms.points.offset
    if not offset:
        return diff
    d = diff.norm(dim=-1, keepdim=True).clamp_min(1e-12)
    return diff * (1.0 - offset / d)


def _floor_depth(problem: _Problem, posed: _Posed):
    """min(0, z - h) of the floor places.  -> (frame, v)"""
    return (posed.floor[..., 2] - problem.terms.floor.height).clamp_max(0.0)


def _rotvecs(rotations):
    """Rotation vectors of rotation matrices (torch, no gradient).  (..., 3, 3) -> (..., 3)"""
    import torch

    flat = rotations.reshape(-1, 3, 3).numpy()
    return torch.from_numpy(Rotation.from_matrix(flat).as_rotvec().reshape(rotations.shape[:-1]))


def _relative(problem: _Problem, state: State, frames: _Frames):
    """Each held bone's local rotation relative to its anchor, Q = A^T L.  -> (frame, held, 3, 3)"""
    return frames.anchor.transpose(-1, -2) @ state.local[:, problem.held]


def _energies(problem: _Problem, state: State, posed: _Posed, frames: _Frames):
    """Each frame's energy (the module's text, without E_beta).  -> (frame,)"""
    data = ((_residuals(problem, posed, frames) ** 2).sum(-1) * frames.weight).sum(1)  # Eq. (8), Milef et al. 2024
    q = _relative(problem, state, frames)
    if problem.terms.prior.form == "angle":
        psi = (_rotvecs(q) ** 2).sum((1, 2))
    else:
        psi = (3.0 - q.diagonal(dim1=-2, dim2=-1).sum(-1)).sum(1)  # 2 (1 - cos angle)
    energy = data + frames.prior * psi  # E_Theta, Eq. (5)
    if problem.floor_skin is not None:
        energy = energy + problem.terms.floor.weight * (_floor_depth(problem, posed) ** 2).sum(1)
    return energy


def _shape_energy(problem: _Problem, phenotype: np.ndarray) -> float:
    if not problem.terms.shape_weight:
        return 0.0
    return float(problem.terms.shape_weight * ((phenotype - problem.terms.shape_anchor) ** 2).sum())  # Eq. (2)


# --- normal equations ------------------------------------------------------------------------------------------------


_LEVI = np.zeros((3, 3, 3))
_LEVI[0, 1, 2] = _LEVI[1, 2, 0] = _LEVI[2, 0, 1] = 1.0
_LEVI[0, 2, 1] = _LEVI[2, 1, 0] = _LEVI[1, 0, 2] = -1.0


@dataclass(frozen=True)
class _Metric:
    """The points' Gauss-Newton metric S = c I + (1 - c) u u^T, from the Hessian of (d - delta)^2 / 2 in v:
    u u^T + (1 - delta / d) (I - u u^T), its tangent part clamped to [0, 1] (a marker nearer the skin than delta
    would make it negative)."""

    iso: object  # (frame, n) c
    radial: object  # (frame, n, 3) u


def _metric(problem: _Problem, posed: _Posed, frames: _Frames) -> _Metric | None:
    offset = problem.terms.points.offset
    if not offset:
        return None  # S = I
    diff = posed.points - frames.target
    d = diff.norm(dim=-1).clamp_min(1e-12)
    return _Metric((1.0 - offset / d).clamp(0.0, 1.0), diff / d[..., None])


def _radial_rows(lever, radial):
    """u^T J of each point: (a_nb x u) per seen bone, then u.  -> (frame, n, P)"""
    import torch

    frames, n, seen, _ = lever.shape
    turn = torch.linalg.cross(lever, radial[:, :, None].expand_as(lever), dim=-1)
    return torch.cat([turn.reshape(frames, n, 3 * seen), radial], -1)


def _point_equations(lever, residual, weight, metric: _Metric | None):
    """J^T W S J and J^T W r of the points (seen bones' world rotations, then the root's head): J = [-[a_nb]x ...,
    I], S the metric (I without an offset).  lever (frame, n, seen, 3), residual (frame, n, 3), weight (frame, n)
    -> (frame, P, P), (frame, P)"""
    import torch

    frames, _, seen, _ = lever.shape
    iso = weight if metric is None else weight * metric.iso
    root = iso.sqrt()[..., None]
    a = lever * root[..., None]  # sqrt(w c) a
    gram = a.reshape(frames, -1, seen * 3).transpose(1, 2) @ a.reshape(frames, -1, seen * 3)
    gram = gram.reshape(frames, seen, 3, seen, 3)  # G[j, alpha, l, beta] = sum_n w c a_nj,alpha a_nl,beta
    trace = gram.diagonal(dim1=2, dim2=4).sum(-1)  # (frame, seen, seen)
    eye = torch.eye(3, dtype=torch.float64)
    rot = trace[:, :, None, :, None] * eye[None, None, :, None, :] - gram.transpose(2, 4)  # [a_j]x^T [a_l]x summed
    p = 3 * seen + 3
    lhs = torch.zeros(frames, p, p, dtype=torch.float64)
    lhs[:, :3 * seen, :3 * seen] = rot.reshape(frames, 3 * seen, 3 * seen)
    levi = torch.from_numpy(_LEVI)
    cross = torch.einsum("gab,fsa->fsgb", levi, (a * root[..., None]).sum(1))  # [sum_n w c a_nj]x
    lhs[:, :3 * seen, 3 * seen:] = cross.reshape(frames, 3 * seen, 3)
    lhs[:, 3 * seen:, :3 * seen] = cross.reshape(frames, 3 * seen, 3).transpose(1, 2)
    lhs[:, 3 * seen:, 3 * seen:] = iso.sum(1)[:, None, None] * eye
    if metric is not None:  # the radial part, (1 - c) (u^T J)^T (u^T J)
        rows = _radial_rows(lever, metric.radial)
        lhs = lhs + rows.transpose(1, 2) @ (rows * (weight * (1.0 - metric.iso))[..., None])
    moments = torch.einsum("fnsa,fnb->fsab", lever, residual * weight[..., None])  # sum_n w a_nj r_n^T
    rhs = torch.cat([torch.einsum("gab,fsab->fsg", levi, moments).reshape(frames, -1),
                     (residual * weight[..., None]).sum(1)], 1)  # J^T W r: sum_n w a_nj x r_n, sum_n w r_n
    return lhs, rhs


@dataclass(frozen=True)
class _Contacts:
    """The floor places below the floor: their frame, place, depth min(0, z - h) and height rows of J."""

    frame: object  # (m,) long
    place: object  # (m,) long
    depth: object  # (m,)
    rows: object  # (m, P)


def _contacts(problem: _Problem, posed: _Posed, rest: Rest) -> _Contacts | None:
    """The height rows (a_y, -a_x, 0) per seen bone, then (0, 0, 1), of the floor places below the floor."""
    import torch

    if problem.floor_skin is None:
        return None
    depth = _floor_depth(problem, posed)  # (frame, v)
    frame, place = torch.nonzero(depth < 0, as_tuple=True)
    skin = problem.floor_skin
    bones = skin.bones[place]  # (m, k)
    offset = rest.points[1][place][:, None] - rest.heads[bones]  # (m, k, 3)
    moved = (posed.rots[frame[:, None], bones] @ offset[..., None])[..., 0] + posed.heads[frame[:, None], bones]
    seen_heads = posed.heads[:, torch.from_numpy(np.flatnonzero(problem.body.seen_bones))]
    lever = torch.einsum("mks,mka->msa", skin.chains[place], moved) \
        - skin.reach[place][..., None] * seen_heads[frame]  # (m, seen, 3)
    rows = torch.zeros(len(frame), lever.shape[1], 3, dtype=torch.float64)
    rows[..., 0], rows[..., 1] = lever[..., 1], -lever[..., 0]
    ends = torch.zeros(len(frame), 3, dtype=torch.float64)
    ends[:, 2] = 1.0
    rows = torch.cat([rows.reshape(len(frame), 3 * lever.shape[1]), ends], 1)
    return _Contacts(frame, place, depth[frame, place], rows)


def _equations(problem: _Problem, state: State, rest: Rest, posed: _Posed, frames: _Frames):
    """Half the Gauss-Newton Hessian and gradient of every frame's energy in its pose.  -> (frame, P, P), (frame, P)
    and what the phenotype's rows need (levers, the floor's contacts)."""
    skin = _gather(problem.skin, frames.place)
    lever = _levers(problem, posed.heads, posed.moved, skin)
    lhs, rhs = _point_equations(lever, _residuals(problem, posed, frames), frames.weight,
                                _metric(problem, posed, frames))
    contacts = _contacts(problem, posed, rest)
    if contacts is not None and len(contacts.frame):
        w = problem.terms.floor.weight
        lhs.index_add_(0, contacts.frame, w * contacts.rows[:, :, None] * contacts.rows[:, None, :])
        rhs.index_add_(0, contacts.frame, w * contacts.rows * contacts.depth[:, None])
    _add_pose_prior(problem, state, posed, frames, lhs, rhs)
    return lhs, rhs, lever, contacts


def _add_pose_prior(problem: _Problem, state: State, posed: _Posed, frames: _Frames, lhs, rhs) -> None:
    """E_Theta: for the held bones, in w = A^T M_parent^T delta: "angle" linearised, ||rho + w||^2 (rho the rotation
    vector of Q); "chord" its gradient vee(Q - Q^T) and Hessian 2 I (half of each here)."""
    import torch

    q = _relative(problem, state, frames)  # (frame, held, 3, 3)
    if problem.terms.prior.form == "angle":
        g = _rotvecs(q)
    else:
        s = q - q.transpose(-1, -2)
        g = 0.5 * torch.stack([s[..., 2, 1], s[..., 0, 2], s[..., 1, 0]], -1)  # sin(angle) axis
    parents = np.maximum(problem.body.parents[problem.held.numpy()], 0)
    frame_of = posed.rots[:, torch.from_numpy(parents)]  # M_parent (frame, held, 3, 3)
    if problem.terms.prior.root:
        frame_of = frame_of.clone()
        frame_of[:, 0] = torch.eye(3, dtype=torch.float64)  # the root's local rotation is its world one
    kappa = frames.prior[:, None]  # (frame, 1)
    index = (3 * problem.held_in_seen[:, None] + torch.arange(3)).reshape(-1)
    lhs[:, index, index] += kappa.repeat_interleave(3 * len(problem.held), 1)
    grad = (frame_of @ frames.anchor @ g[..., None])[..., 0] * kappa[..., None]  # (frame, held, 3)
    rhs[:, index] += grad.reshape(len(grad), -1)


def _head_derivatives(problem: _Problem, rots, d_heads):
    """d h_b / d phenotype from the rest heads' derivatives: dh_b = dh_parent + M_parent (dr_b - dr_parent) (forward
    kinematics' heads, differentiated with the rotations held).  rots (frame, bone, 3, 3) -> (frame, bone, 3, 6)"""
    import torch

    dh = torch.zeros(rots.shape[:2] + (3, 6), dtype=torch.float64)
    for bones, up in problem.body.levels:
        dh[:, bones] = dh[:, up] + rots[:, up] @ (d_heads[bones] - d_heads[up])
    return dh


def _shape_rows(rots, dh, d_heads, dense, d_points):
    """d place / d phenotype: sum_k w_nk (M_k (dx_n - dr_k) + dh_k) = B_n dx_n - sum_k w_nk (M_k dr_k - dh_k),
    B_n = sum_k w_nk M_k.  rots (frame, bone, 3, 3), dh (frame, bone, 3, 6), dense (n, bone) or (frame, n, bone)
    weights, d_points (n, 3, 6) or (frame, n, 3, 6) -> (frame, n, 3, 6)"""
    frames, bones = rots.shape[:2]
    blend = (dense @ rots.reshape(frames, bones, 9)).reshape(frames, -1, 3, 3)  # B_n
    carried = (rots @ d_heads - dh).reshape(frames, bones, 18)  # M_k dr_k - dh_k
    return blend @ d_points - (dense @ carried).reshape(frames, -1, 3, 6)


def _shape_blocks(problem: _Problem, rest: Rest, posed: _Posed, frames: _Frames, lever, contacts):
    """The phenotype's rows of the normal equations: J_p^T W J_phi (frame, P, 6), J_phi^T W J_phi (frame, 6, 6),
    J_phi^T W r (frame, 6)."""
    import torch

    dh = _head_derivatives(problem, posed.rots, rest.d_heads)
    jac = _shape_rows(posed.rots, dh, rest.d_heads, problem.dense[frames.place],
                      rest.d_points[0][frames.place])  # (frame, n, 3, 6)
    n_frames, _, seen, _ = lever.shape
    metric = _metric(problem, posed, frames)
    iso = frames.weight if metric is None else frames.weight * metric.iso
    weighted = jac * iso[..., None, None]
    lever_jac = torch.einsum("fnsa,fnbm->fsabm", lever, weighted)  # (frame, seen, 3, 3, 6)
    rot = torch.einsum("gab,fsabm->fsgm", torch.from_numpy(_LEVI), lever_jac)  # sum_n w c [a_nj]x J_n
    cross = torch.cat([rot.reshape(n_frames, 3 * seen, 6), weighted.sum(1)], 1)
    square = torch.einsum("fcam,fcan->fmn", weighted, jac)
    if metric is not None:  # the radial part of S
        radial_jac = torch.einsum("fna,fnam->fnm", metric.radial, jac) * (frames.weight * (1.0 - metric.iso))[..., None]
        cross = cross + _radial_rows(lever, metric.radial).transpose(1, 2) @ radial_jac
        square = square + torch.einsum("fna,fnam->fnm", metric.radial, jac).transpose(1, 2) @ radial_jac
    gradient = torch.einsum("fnam,fna->fm", jac * frames.weight[..., None, None], _residuals(problem, posed, frames))
    if contacts is not None and len(contacts.frame):
        f, v, w = contacts.frame, contacts.place, problem.terms.floor.weight
        floor_jac = w ** 0.5 * _shape_rows(posed.rots[f], dh[f], rest.d_heads, problem.floor_dense[v][:, None],
                                          rest.d_points[1][v][:, None])[:, 0, 2]  # (m, 6) heights
        rows = w ** 0.5 * contacts.rows
        cross = cross.index_add(0, f, rows[:, :, None] * floor_jac[:, None, :])
        square = square.index_add(0, f, floor_jac[:, :, None] * floor_jac[:, None, :])
        gradient = gradient.index_add(0, f, floor_jac * (w ** 0.5 * contacts.depth)[:, None])
    return cross, square, gradient


# --- steps -----------------------------------------------------------------------------------------------------------


def _apply(problem: _Problem, state: State, posed: _Posed, step) -> State:
    """Turn each seen bone by its world rotation about its head and move the root: L_b <- exp(M_parent^T delta_b) L_b
    (the root's: exp(delta) L_root).  step (frame, P)"""
    import torch

    seen = np.flatnonzero(problem.body.seen_bones)
    frames = step.shape[0]
    delta = step[:, :3 * len(seen)].reshape(frames, len(seen), 3)
    local = state.local.clone()
    parents = np.maximum(problem.body.parents[seen], 0)
    frame_delta = (posed.rots[:, torch.from_numpy(parents)].transpose(-1, -2) @ delta[..., None])[..., 0]
    frame_delta[:, 0] = delta[:, 0]  # the root: its local rotation is its world one
    local[:, torch.from_numpy(seen)] = torch_rodrigues(frame_delta) @ state.local[:, torch.from_numpy(seen)]
    return State(local, state.root + step[:, 3 * len(seen):], state.phenotype)


def _damped(lhs, damping):
    import torch

    diagonal = lhs.diagonal(dim1=1, dim2=2)
    return lhs + torch.diag_embed(damping[:, None] * diagonal + 1e-9)


def _subset(items, idx):
    """A State's or _Posed's chosen frames (index or mask)."""
    kind = type(items)
    return kind(**{k: v if v is None or isinstance(v, np.ndarray) else v[idx] for k, v in vars(items).items()})


def _store(items, idx, new) -> None:
    """Write chosen frames of a State or _Posed in place."""
    for k, v in vars(items).items():
        if v is not None and not isinstance(v, np.ndarray):
            v[idx] = getattr(new, k)


def _solve_chunk(problem: _Problem, state: State, rest: Rest, frames: _Frames, iterations: int,
                 tolerance: float) -> State:
    """Levenberg-Marquardt on every frame's pose, the phenotype fixed; each frame damped on its own and left out
    once a step changes its energy by less than ``tolerance`` (relative) or no step helps."""
    import torch

    posed = _pose(problem, state, rest, frames)
    energy = _energies(problem, state, posed, frames)
    damping = torch.full((state.root.shape[0],), 1e-3, dtype=torch.float64)
    active = torch.ones(state.root.shape[0], dtype=torch.bool)
    for _ in range(iterations):
        idx = torch.nonzero(active)[:, 0]
        whole = bool(active.all())
        sub, sub_posed, sub_frames = (state, posed, frames) if whole else \
            (_subset(state, idx), _subset(posed, idx), frames.take(idx))
        lhs, rhs, _, _ = _equations(problem, sub, rest, sub_posed, sub_frames)
        trial = _apply(problem, sub, sub_posed, torch.linalg.solve(_damped(lhs, damping[idx]), -rhs))
        trial_posed = _pose(problem, trial, rest, sub_frames)
        trial_energy = _energies(problem, trial, trial_posed, sub_frames)
        better = trial_energy < energy[idx]
        gain = (energy[idx] - trial_energy) / energy[idx].clamp_min(1e-30)
        _store(state, idx[better], _subset(trial, better))
        _store(posed, idx[better], _subset(trial_posed, better))
        energy[idx[better]] = trial_energy[better]
        damping[idx] = torch.where(better, damping[idx] / 3.0, damping[idx] * 4.0)
        active[idx[(gain.abs() < tolerance) | (damping[idx] > GIVE_UP)]] = False
        if not active.any():
            break
    return state


def solve_poses(body: SolverBody, places: Places, terms: Terms, start: State, iterations: int = 30,
                tolerance: float = 1e-3, chunk: int = 8, skin: Skin | None = None) -> State:
    """Every frame's pose with the phenotype fixed (``start.phenotype``), ``chunk`` frames at a time (bounded
    memory); ``skin``: the places' (``skin_of``) when the caller holds it."""
    import torch

    check_terms(terms, places, start.root.shape[0])
    problem = _problem(body, places, terms, skin)
    frames = _frames_of(problem)
    rest = problem.rest(start.phenotype)
    parts = []
    with torch.no_grad():
        for s in range(0, start.root.shape[0], chunk):
            part = slice(s, s + chunk)
            parts.append(_solve_chunk(problem, _subset(start, part), rest, frames.take(part), iterations, tolerance))
    return State(torch.cat([p.local for p in parts]), torch.cat([p.root for p in parts]), start.phenotype)


def solve_take(body: SolverBody, places: Places, terms: Terms, start: State, iterations: int = 30,
               tolerance: float = 1e-3, skin: Skin | None = None) -> State:
    """The phenotype (in [0, 1]) and every frame's pose together, one damping for all (Schur complement on the
    phenotype). The rest shape's phenotype derivatives are evaluated again only once the phenotype has moved
    SHAPE_REFRESH from where they were taken (Anny's rest shape is piecewise linear in it), or when a step on them
    fails."""
    import torch

    check_terms(terms, places, start.root.shape[0])
    if terms.shape_anchor is None:
        raise FitError("solve_take fits the phenotype: give the terms a shape_anchor (and a shape_weight)")
    problem = _problem(body, places, terms, skin)
    frames = _frames_of(problem)
    with torch.no_grad():
        return _solve_take(problem, replace(start, local=start.local.clone(), root=start.root.clone()), frames,
                           iterations, tolerance)


def _solve_take(problem: _Problem, state: State, frames: _Frames, iterations: int, tolerance: float) -> State:
    """Levenberg-Marquardt on the phenotype and every frame's pose in one step (Schur complement), each frame's
    pose damped on its own and the phenotype on its own. A trial phenotype is kept when the whole energy falls with
    each frame at the better of its old and its new pose under it; a frame whose new pose did worse keeps its old one
    and is damped more (one frame far from its minimum does not hold the others back)."""
    import torch

    rest = problem.rest(state.phenotype, derivatives=True)
    derived_at = state.phenotype
    posed = _pose(problem, state, rest, frames)
    energy = _energies(problem, state, posed, frames)
    total = float(energy.sum()) + _shape_energy(problem, state.phenotype)
    damping = torch.full((state.root.shape[0],), 1e-3, dtype=torch.float64)
    shape_damping = 1e-3
    for _ in range(iterations):
        step = _take_step(problem, state, rest, posed, frames, damping, shape_damping)
        phenotype = np.clip(state.phenotype + step[1].numpy(), 0.0, 1.0)
        refresh = np.abs(phenotype - derived_at).max() > SHAPE_REFRESH
        trial_rest = problem.rest(phenotype, derivatives=refresh)
        if not refresh:
            trial_rest = replace(trial_rest, d_heads=rest.d_heads, d_points=rest.d_points)
        trial = _apply(problem, state, posed, step[0])
        trial.phenotype = phenotype
        trial_posed = _pose(problem, trial, trial_rest, frames)
        trial_energy = _energies(problem, trial, trial_posed, frames)
        if (phenotype != state.phenotype).any():  # each frame's old pose under the new phenotype
            kept = replace(state, phenotype=phenotype)
            kept_posed = _pose(problem, kept, trial_rest, frames)
            kept_energy = _energies(problem, kept, kept_posed, frames)
        else:
            kept, kept_posed, kept_energy = state, posed, energy
        better = trial_energy < kept_energy
        trial_energy = torch.where(better, trial_energy, kept_energy)
        trial_total = float(trial_energy.sum()) + _shape_energy(problem, phenotype)
        gain = (total - trial_total) / max(total, 1e-30)
        if trial_total < total:
            _store(kept, better, _subset(trial, better))
            _store(kept_posed, better, _subset(trial_posed, better))
            state, rest, posed, energy, total = kept, trial_rest, kept_posed, trial_energy, trial_total
            derived_at = phenotype if refresh else derived_at
            shape_damping /= 3.0
        elif (derived_at != state.phenotype).any():  # a step failed on old derivatives: take them here first
            rest, derived_at = problem.rest(state.phenotype, derivatives=True), state.phenotype
            continue
        else:
            shape_damping *= 4.0
        damping = torch.where(better, damping / 3.0, damping * 4.0)
        if abs(gain) < tolerance or (damping.min() > GIVE_UP and shape_damping > GIVE_UP):
            break
    return state


def _take_step(problem: _Problem, state: State, rest: Rest, posed: _Posed, frames: _Frames, damping,
               shape_damping: float):
    """One damped Gauss-Newton step of poses and phenotype: the phenotype's through the Schur complement
    H_phi,phi - sum_f H_phi,p H_pp^-1 H_p,phi, then each frame's pose.  -> (frame, P), (6,)"""
    import torch

    lhs, rhs, lever, contacts = _equations(problem, state, rest, posed, frames)
    cross, shape_lhs, shape_rhs = _shape_blocks(problem, rest, posed, frames, lever, contacts)
    weight = problem.terms.shape_weight
    shape_lhs = shape_lhs.sum(0) + weight * torch.eye(6, dtype=torch.float64) + 1e-9 * torch.eye(6, dtype=torch.float64)
    shape_rhs = shape_rhs.sum(0) + weight * torch.from_numpy(state.phenotype - problem.terms.shape_anchor)  # E_beta
    solved = torch.linalg.solve(_damped(lhs, damping), torch.cat([cross, rhs[..., None]], -1))  # H_pp^-1 [H_p,phi, g_p]
    schur = shape_lhs + shape_damping * torch.diag_embed(shape_lhs.diagonal()) \
        - (cross.transpose(1, 2) @ solved[..., :6]).sum(0)
    d_shape = torch.linalg.solve(schur, -shape_rhs + (cross.transpose(1, 2) @ solved[..., 6:]).sum(0)[:, 0])
    return -solved[..., 6] - solved[..., :6] @ d_shape, d_shape


def _total(problem: _Problem, state: State, posed: _Posed, frames: _Frames) -> float:
    return float(_energies(problem, state, posed, frames).sum()) + _shape_energy(problem, state.phenotype)


def energy(body: SolverBody, places: Places, terms: Terms, fit: BodyFit) -> float:
    """E of the module's text for a body over the take (a check on solvers)."""
    import torch

    problem = _problem(body, places, terms)
    state = State.of(fit)
    frames = _frames_of(problem)
    with torch.no_grad():
        return _total(problem, state, _pose(problem, state, problem.rest(state.phenotype), frames), frames)


def gradient(body: SolverBody, places: Places, terms: Terms, fit: BodyFit) -> tuple[np.ndarray, np.ndarray]:
    """The gradient of E (a check on solvers): per frame in the solvers' parameters (each seen bone's world
    rotation about its head, then the root's head) and in the phenotype.  -> (frame, 3 seen + 3), (6,)"""
    import torch

    problem = _problem(body, places, terms)
    state = State.of(fit)
    frames = _frames_of(problem)
    with torch.no_grad():
        rest = problem.rest(state.phenotype, derivatives=True)
        posed = _pose(problem, state, rest, frames)
        _, rhs, lever, contacts = _equations(problem, state, rest, posed, frames)
        _, _, shape = _shape_blocks(problem, rest, posed, frames, lever, contacts)
    anchor = terms.shape_anchor if terms.shape_anchor is not None else state.phenotype
    return 2.0 * rhs.numpy(), 2.0 * (shape.sum(0).numpy() + terms.shape_weight * (state.phenotype - anchor))

"""Hole filling for the checkerboard suit (Chen, Park, Macit, Kavan 2021, §5): non-articulated displacements
interpolated in the rest pose, then skinned back.

Triangulation leaves holes where a corner is occluded. A body model fitted to the observed corners
(tasks/suit/body_fit) explains most of their motion; what it does not explain, the non-articulated displacement
Delta v~ = LBS^-1(p) - v~ of each observed corner (breathing, flesh, the suit's own stretch), is measured in the rest
pose by inverse skinning (``unpose``), interpolated to every corner by a constrained quadratic problem (Eq. 8,
``fill_sequence``) and skinned back (``repose``):

    min_X  sum_frames || L X_f ||^2  +  lambda sum_corners || X_c(t-1) - 2 X_c(t) + X_c(t+1) ||^2   s.t.  C X = D

per coordinate, with L the cotangent Laplacian of the rest-pose corner mesh (``cotangent_laplacian``), the
temporal term the corners' accelerations (``temporal_laplacian``), lambda = 100, and the observed corners'
displacements as hard constraints. The paper solves the KKT system of this problem; eliminating the constrained
unknowns gives the same optimum from a smaller symmetric positive definite system (``method="reduced"``, the
default: about 20 times faster on 150 frames of 1,500 corners, see benchmarks/suit_fill.py); both are kept and
tested to agree. Long takes are
solved in windows of 150 frames overlapping by 50, blended linearly over each overlap.

What cannot be filled: Eq. (8) leaves, on each connected part of the corner mesh, a displacement that is the same
for all its corners and affine in time free (zero Laplacian, zero acceleration). A part observed in two frames or
more of a window pins it; a part observed in fewer (a whole window without observations, a patch of the suit seen in
one frame only, a corner in no cell seen once) is not filled: its points stay NaN there (``observed`` False), and
the caller decides (e.g. the body model's position, Delta v~ = 0). A window of one or two frames has no temporal
term: a part must be observed in each of its frames. Corners in no cell have no spatial term: they are filled from
their own trajectory alone (the temporal term: a cubic-spline-like curve through their samples).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
import scipy.sparse as sp
import xarray as xr
from scipy.sparse.csgraph import connected_components
from scipy.sparse.linalg import splu

from mocapflow.tasks.shared.cameras import camera_of
from mocapflow.tasks.shared.mesh_body import PHENOTYPE_NAMES, Phenotype, part_of_bone
from mocapflow.tasks.shared.place_fit import reference_body
from mocapflow.tasks.shared.solver_body import SolverBody
from mocapflow.tasks.suit.body_fit import BodyFitConfig, fit_body
from mocapflow.tasks.suit.limbs import LimbConfig, limb_pixels, limb_points, limbs_of, unclaimed, views_of


METHODS = ("reduced", "kkt")
COT_MAX = 1.0 / np.tan(np.radians(1.0))  # an angle's cotangent is clamped to +-cot(1 degree) (degenerate triangles)
KKT_SCALE = 1e3  # the KKT system's constraint rows, times Q's largest entry
KKT_PIVOT = 0.01  # SuperLU's diagonal pivot threshold on the KKT system


class FillError(ValueError):
    """A corner mesh, displacement sequence, skinning input or setting hole filling cannot use."""


@dataclass(frozen=True)
class FillConfig:
    temporal_weight: float = 100.0  # lambda of Eq. (8), Chen et al. 2021
    window: int = 150  # frames per solve (§5, Chen et al. 2021)
    overlap: int = 50  # frames shared by consecutive windows, blended linearly
    method: str = "reduced"  # "reduced": constrained unknowns eliminated; "kkt": the paper's KKT system

    def __post_init__(self):
        if not self.temporal_weight > 0:
            raise FillError(f"temporal_weight must be > 0 (got {self.temporal_weight}); Eq. (8) uses 100")
        if self.window < 3 or not 0 <= self.overlap < self.window:
            raise FillError(f"windows need window >= 3 and 0 <= overlap < window (got window={self.window}, "
                            f"overlap={self.overlap}); the paper uses 150 and 50")
        if self.method not in METHODS:
            raise FillError(f"unknown fill method {self.method!r}; choose one of {', '.join(METHODS)}")


# --- the rest-pose corner mesh ------------------------------------------------------------------------------------


def _check_mesh(rest: np.ndarray, cells: np.ndarray) -> None:
    if rest.ndim != 2 or rest.shape[1] != 3:
        raise FillError(f"rest positions must be (corner, 3), got shape {rest.shape}")
    if not np.isfinite(rest).all():
        bad = np.flatnonzero(~np.isfinite(rest).all(1))
        raise FillError(f"rest positions of {len(bad)} corners are not finite (first: corner {bad[0]}); every "
                        "corner needs a rest position (fill missing ones from the body model)")
    if cells.ndim != 2 or cells.shape[1] != 4 or (cells.size and not np.issubdtype(cells.dtype, np.integer)):
        raise FillError(f"cells must be integer (cell, 4) corner indices, got {cells.dtype} {cells.shape}")
    if cells.size and (cells.min() < 0 or cells.max() >= len(rest)):
        raise FillError(f"cells index corners {cells.min()}..{cells.max()}, but there are {len(rest)} corners")


def quad_triangles(rest: np.ndarray, cells: np.ndarray) -> np.ndarray:
    """Each quad (cyclic corners a b c d) cut along its shorter rest diagonal into two triangles.
    rest (corner, 3), cells (cell, 4) -> (2 cell, 3)"""
    a, b, c, d = cells.T
    ac = np.linalg.norm(rest[a] - rest[c], axis=1) <= np.linalg.norm(rest[b] - rest[d], axis=1)
    first = np.where(ac[:, None], np.column_stack([a, b, c]), np.column_stack([a, b, d]))
    second = np.where(ac[:, None], np.column_stack([a, c, d]), np.column_stack([b, c, d]))
    return np.concatenate([first, second])


def _cotangents(rest: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """Cotangent of each triangle's angle at each of its corners, clamped to +-COT_MAX.  -> (triangle, 3)"""
    p = rest[triangles]  # (tri, 3, 3)
    cots = []
    for k in range(3):
        e1 = p[:, (k + 1) % 3] - p[:, k]
        e2 = p[:, (k + 2) % 3] - p[:, k]
        dot = (e1 * e2).sum(1)
        sin_area = np.linalg.norm(np.cross(e1, e2), axis=1)  # |e1||e2| sin(angle)
        cots.append(dot / np.maximum(sin_area, 1e-300))
    return np.clip(np.column_stack(cots), -COT_MAX, COT_MAX)


def cotangent_laplacian(rest: np.ndarray, cells: np.ndarray) -> sp.csr_matrix:
    """The cotangent-weighted Laplacian of the rest-pose corner mesh (§5, Eq. 8, Chen et al. 2021).

    rest (corner, 3), cells (cell, 4) -> (corner, corner) CSR, (L x)_i = sum_j w_ij (x_i - x_j),
    w_ij = (cot alpha_ij + cot beta_ij) / 2 over the triangles of the quads (``quad_triangles``). Robust to bad
    triangles: each cotangent is clamped to +-cot(1 degree) (degenerate triangles), and each edge's summed weight
    to >= 0 (an edge opposite two obtuse angles, where the plain cotangent weight turns negative). Not divided
    by the vertex areas: both terms of Eq. (8) then measure displacements in metres, so lambda is unitless.
    Corners in no cell have empty rows: no spatial term.
    """
    rest = np.asarray(rest, np.float64)
    cells = np.asarray(cells)
    _check_mesh(rest, cells)
    n = len(rest)
    if not len(cells):
        return sp.csr_matrix((n, n))
    triangles = quad_triangles(rest, cells)
    cot = _cotangents(rest, triangles)  # (tri, 3), the angle at corner k faces edge (k+1, k+2)
    i = np.concatenate([triangles[:, (k + 1) % 3] for k in range(3)])
    j = np.concatenate([triangles[:, (k + 2) % 3] for k in range(3)])
    w = 0.5 * np.concatenate([cot[:, k] for k in range(3)])
    lo, hi = np.minimum(i, j), np.maximum(i, j)
    edges = sp.coo_matrix((w, (lo, hi)), shape=(n, n)).tocsr()  # sums both triangles of each edge
    edges.data = np.maximum(edges.data, 0.0)  # clamp: non-negative edge weights
    edges.eliminate_zeros()
    weights = edges + edges.T
    return (sp.diags(np.asarray(weights.sum(1)).ravel()) - weights).tocsr()


def temporal_laplacian(frames: int) -> sp.csr_matrix:
    """Second differences over a window (Eq. 8: a corner's acceleration).  -> (frame - 2, frame) CSR"""
    if frames < 3:
        return sp.csr_matrix((0, max(frames, 0)))
    return sp.diags([np.ones(frames - 2), -2 * np.ones(frames - 2), np.ones(frames - 2)], [0, 1, 2],
                    shape=(frames - 2, frames), format="csr")


def window_matrix(laplacian: sp.spmatrix, frames: int, temporal_weight: float) -> sp.csr_matrix:
    """The quadratic form of Eq. (8) over a window, unknowns ordered frame-major (f * corner + c).
    -> (frame * corner, frame * corner):  I_f (x) L^T L  +  lambda  D2^T D2 (x) I_c"""
    n = laplacian.shape[0]
    spatial = (laplacian.T @ laplacian).tocsr()
    d2 = temporal_laplacian(frames)
    q = sp.kron(sp.identity(frames), spatial) + temporal_weight * sp.kron(d2.T @ d2, sp.identity(n))
    return q.tocsr()


# --- one window -----------------------------------------------------------------------------------------------------


def _components(laplacian: sp.spmatrix) -> np.ndarray:
    """Connected part of the corner mesh each corner belongs to (through non-zero weights).  -> (corner,)"""
    graph = sp.csr_matrix(laplacian, copy=True)
    graph.eliminate_zeros()
    return connected_components(graph, directed=False)[1]


def fillable(observed: np.ndarray, laplacian: sp.spmatrix) -> np.ndarray:
    """Corners Eq. (8) fixes in a window: their part of the mesh is observed in >= 2 distinct frames (in every frame
    of a window of 1 or 2 frames, which has no temporal term).  observed (frame, corner) bool -> (corner,) bool"""
    label = _components(laplacian)
    seen = np.zeros((observed.shape[0], label.max() + 1), bool)  # (frame, part)
    frame, corner = np.nonzero(observed)
    seen[frame, label[corner]] = True
    return (seen.sum(0) >= min(2, observed.shape[0]))[label]


def _blocks(q: sp.csr_matrix, unknown: np.ndarray) -> tuple[sp.csc_matrix, sp.csr_matrix]:
    """Q_uu and Q_uo of a form and a mask of its unknowns (the rest known)."""
    unknown_index = np.cumsum(unknown) - 1
    known_index = np.cumsum(~unknown) - 1
    coo = q.tocoo()
    row_u = unknown[coo.row]
    uu = row_u & unknown[coo.col]
    uo = row_u & ~unknown[coo.col]
    nu, no = int(unknown.sum()), int((~unknown).sum())
    q_uu = sp.csc_matrix((coo.data[uu], (unknown_index[coo.row[uu]], unknown_index[coo.col[uu]])), shape=(nu, nu))
    q_uo = sp.csr_matrix((coo.data[uo], (unknown_index[coo.row[uo]], known_index[coo.col[uo]])), shape=(nu, no))
    return q_uu, q_uo


def _factor(matrix: sp.spmatrix, pivot_threshold: float = 0.0):
    """SuperLU of a structurally symmetric matrix: minimum degree on A + A^T, diagonal pivots preferred."""
    return splu(sp.csc_matrix(matrix), permc_spec="MMD_AT_PLUS_A",
                options={"SymmetricMode": True, "DiagPivotThresh": pivot_threshold})


def _solve_reduced(q: sp.csr_matrix, known: np.ndarray, values: np.ndarray) -> np.ndarray:
    """Eq. (8): min x^T Q x with x[known] = values, the known unknowns eliminated:  Q_uu x_u = -Q_uo d.  -> (n, 3)"""
    x = np.zeros((len(known), values.shape[1]))
    x[known] = values
    if known.all():
        return x
    q_uu, q_uo = _blocks(q, ~known)
    x[~known] = _factor(q_uu).solve(-(q_uo @ values))
    return x


def _solve_kkt(q: sp.csr_matrix, known: np.ndarray, values: np.ndarray) -> np.ndarray:
    """The same optimum from the KKT system [[Q, C^T], [C, 0]] [x; mu] = [0; D] (§5, Chen et al. 2021).  -> (n, 3)

    The system is symmetric indefinite (zero block); scipy's one sparse direct solver is SuperLU (LU with
    threshold pivoting). Its constraint rows are scaled far above Q's entries (C, D -> sC, sD: the same x), so each
    constrained unknown is pivoted on its own constraint row, whose single entry eliminates it without fill.
    """
    n, m = len(known), int(known.sum())
    scale = KKT_SCALE * abs(q).max()  # C and D scaled alike: the same solution (see above)
    c = sp.csr_matrix((np.full(m, scale), (np.arange(m), np.flatnonzero(known))), shape=(m, n))  # selector C
    kkt = sp.bmat([[q, c.T], [c, None]], format="csc")
    rhs = np.zeros((n + m, values.shape[1]))
    rhs[n:] = scale * values
    x = _factor(kkt, KKT_PIVOT).solve(rhs)[:n]
    x[known] = values  # exact to the last bit (the factorization meets them to rounding)
    return x


def solve_window(displacement: np.ndarray, laplacian: sp.spmatrix, config: FillConfig) -> np.ndarray:
    """Eq. (8) on one window.  displacement (frame, corner, 3), NaN where unobserved -> (frame, corner, 3), the
    observed values kept, NaN where unobserved on corners the window cannot fix (``fillable``)."""
    frames = displacement.shape[0]
    observed = np.isfinite(displacement).all(-1)  # (frame, corner)
    keep = fillable(observed, laplacian)  # (corner,)
    out = np.where(observed[..., None], displacement, np.nan)
    if not keep.any():
        return out
    sub = sp.csr_matrix(laplacian)[keep][:, keep] if not keep.all() else sp.csr_matrix(laplacian)
    q = window_matrix(sub, frames, config.temporal_weight)  # Eq. (8)
    known = observed[:, keep].ravel()  # frame-major, as the form
    values = displacement[:, keep].reshape(-1, 3)[known]
    solve = _solve_kkt if config.method == "kkt" else _solve_reduced
    out[:, keep] = solve(q, known, values).reshape(frames, int(keep.sum()), 3)
    return out


# --- a whole take ----------------------------------------------------------------------------------------------------


def windows(frames: int, config: FillConfig) -> list[tuple[int, int]]:
    """[start, stop) of each window: every window - overlap frames, the last one cut at the take's end (at least
    overlap + 1 frames long); a take shorter than a window is one window."""
    step = config.window - config.overlap
    spans = [(0, min(config.window, frames))]
    while spans[-1][1] < frames:
        start = spans[-1][0] + step
        spans.append((start, min(start + config.window, frames)))
    return spans


def blend_weights(spans: list[tuple[int, int]]) -> list[np.ndarray]:
    """Each window's weight per frame: 1, ramping linearly over the frames it shares with a neighbour, so that the
    weights of two overlapping windows sum to 1 on every shared frame.  -> [(window frames,)]"""
    out = []
    for k, (start, stop) in enumerate(spans):
        t = np.arange(start, stop, dtype=np.float64)
        w = np.ones(stop - start)
        if k > 0 and spans[k - 1][1] > start:  # rising over the overlap with the previous window
            shared = spans[k - 1][1] - start
            w = np.minimum(w, (t - start + 1) / (shared + 1))
        if k + 1 < len(spans) and spans[k + 1][0] < stop:  # falling over the overlap with the next window
            shared = stop - spans[k + 1][0]
            w = np.minimum(w, (stop - t) / (shared + 1))
        out.append(w)
    return out


def _check_sequence(displacement: np.ndarray, laplacian: sp.spmatrix) -> None:
    if displacement.ndim != 3 or displacement.shape[2] != 3:
        raise FillError(f"displacements must be (frame, corner, 3), got shape {displacement.shape}")
    n = displacement.shape[1]
    if not sp.issparse(laplacian) or laplacian.shape != (n, n):
        raise FillError(f"the Laplacian must be a sparse ({n}, {n}) matrix for {n} corners, got "
                        f"{type(laplacian).__name__} {getattr(laplacian, 'shape', None)}")
    if displacement.shape[0] < 1:
        raise FillError("the displacement sequence has no frame; give at least one")
    if np.isinf(displacement).any():
        raise FillError("displacements hold infinite values; mark unobserved corners with NaN")


def fill_sequence(displacement: np.ndarray, laplacian: sp.spmatrix,
                  config: FillConfig = FillConfig()) -> tuple[np.ndarray, np.ndarray]:
    """Fill every corner's non-articulated displacement over a take (Eq. 8, windowed, §5 Chen et al. 2021).

    displacement (frame, corner, 3) in the rest pose, NaN where unobserved (a corner with any NaN coordinate is
    unobserved); laplacian (corner, corner) sparse (``cotangent_laplacian``) -> filled (frame, corner, 3),
    observed (frame, corner) bool. Observed points come back exactly; points no window could fix stay NaN
    (see the module's text). A take with no observation at all is an error.
    """
    displacement = np.asarray(displacement, np.float64)
    _check_sequence(displacement, laplacian)
    observed = np.isfinite(displacement).all(-1)  # (frame, corner)
    if not observed.any():
        raise FillError("no corner is observed in any frame; hole filling needs observations (check the "
                        "triangulation and the body fit)")
    clean = np.where(observed[..., None], displacement, np.nan)
    spans = windows(len(clean), config)
    total = np.zeros(clean.shape)
    weight = np.zeros(clean.shape[:2])
    for (start, stop), w in zip(spans, blend_weights(spans)):
        x = solve_window(clean[start:stop], laplacian, config)  # (window, corner, 3)
        ok = np.isfinite(x).all(-1)
        total[start:stop] += np.where(ok[..., None], w[:, None, None] * x, 0.0)
        weight[start:stop] += w[:, None] * ok
    with np.errstate(invalid="ignore", divide="ignore"):
        filled = np.where(weight[..., None] > 0, total / weight[..., None], np.nan)
    filled[observed] = displacement[observed]  # hard constraints, to the bit
    return filled, observed


# --- skinning: into the rest pose and back ----------------------------------------------------------------------------


def skinning_transforms(weights: np.ndarray, bone_transforms: np.ndarray) -> np.ndarray:
    """Each corner's blended transform, sum_k w_ck T_k (linear blend skinning, §5 Chen et al. 2021).
    weights (corner, bone), bone_transforms (frame, bone, 4, 4) rest -> posed -> (frame, corner, 4, 4)"""
    weights = np.asarray(weights, np.float64)
    bone_transforms = np.asarray(bone_transforms, np.float64)
    if weights.ndim != 2 or bone_transforms.ndim != 4 or bone_transforms.shape[1:] != (weights.shape[1], 4, 4):
        raise FillError(f"skinning takes weights (corner, bone) and bone transforms (frame, bone, 4, 4) with the "
                        f"same bones, got {weights.shape} and {bone_transforms.shape}")
    if not (np.isfinite(weights).all() and np.isfinite(bone_transforms).all()):
        raise FillError("skinning weights or bone transforms hold NaN or inf; every frame needs a pose "
                        "(borrow a neighbour's for frames without one)")
    frames, bones = bone_transforms.shape[:2]
    blended = weights @ bone_transforms.reshape(frames, bones, 16)  # (frame, corner, 16)
    return blended.reshape(frames, len(weights), 4, 4)


def _check_points(points: np.ndarray, transforms: np.ndarray, name: str) -> None:
    if transforms.ndim != 4 or transforms.shape[2:] != (4, 4) or points.shape[-1:] != (3,) \
            or points.shape[:-1] not in (transforms.shape[:2], transforms.shape[1:2]):
        raise FillError(f"{name} takes points (frame, corner, 3) and transforms (frame, corner, 4, 4), got "
                        f"{points.shape} and {transforms.shape}")


def unpose(points: np.ndarray, transforms: np.ndarray) -> np.ndarray:
    """Inverse skinning: the rest position each posed point comes from, through the inverse of its blended
    transform (LBS^-1, §5 Chen et al. 2021).  points (frame, corner, 3) (NaN stays NaN), transforms (frame,
    corner, 4, 4) -> (frame, corner, 3)"""
    points = np.asarray(points, np.float64)
    _check_points(points, transforms, "unpose")
    a, t = transforms[..., :3, :3], transforms[..., :3, 3]
    try:
        return np.linalg.solve(a, (points - t)[..., None])[..., 0]
    except np.linalg.LinAlgError as err:
        raise FillError("a blended skinning transform is singular (weights blending opposite rotations); check "
                        "the skinning weights and bone transforms") from err


def repose(rest_points: np.ndarray, transforms: np.ndarray) -> np.ndarray:
    """Forward skinning of rest positions.  rest_points (frame, corner, 3) or (corner, 3), transforms (frame,
    corner, 4, 4) -> (frame, corner, 3)"""
    rest_points = np.asarray(rest_points, np.float64)
    _check_points(rest_points, transforms, "repose")
    return (transforms[..., :3, :3] @ rest_points[..., None])[..., 0] + transforms[..., :3, 3]


# --- the task ---------------------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class FillSuitConfig:
    fill: FillConfig = FillConfig()
    body: BodyFitConfig = BodyFitConfig()


@dataclass(frozen=True)
class FillDetectionsConfig:
    fill: FillConfig = FillConfig()
    body: BodyFitConfig = BodyFitConfig()
    limbs: LimbConfig = LimbConfig()
    limb_confidence: float = 1.0  # weight of the corners placed on unclaimed detections in the second body fit
    refit_shape_sigma: float = 0.001  # sigma_beta of the second fit, about the first fit's phenotype (held)

    def __post_init__(self):
        if not self.limb_confidence >= 0 or not self.refit_shape_sigma > 0:
            raise FillError(f"limb_confidence must be >= 0 and refit_shape_sigma > 0 (got {self.limb_confidence}, "
                            f"{self.refit_shape_sigma})")


def fill_suit(points: xr.Dataset, images: xr.Dataset, config: FillSuitConfig) -> xr.Dataset:
    """Task: a take's triangulated corners (suit_points) -> every corner in every frame (suit_filled): the body
    fitted to the observed corners, their non-articulated displacements unposed, filled by Eq. (8) and reposed.
    A corner that no window could fill keeps the body model's position (zero displacement)."""
    observed_xyz = points["position"].transpose("frame", "corner", "xyz").values.astype(np.float64)
    body = fit_body(_solver_body(), observed_xyz, images["corner_face"].values, images["corner_bary"].values,
                    config.body)
    return _filled(points, observed_xyz, body, images["cells"].values, config.fill)


def fill_suit_detections(points: xr.Dataset, images: xr.Dataset, corners: xr.Dataset, labels: xr.Dataset,
                         config: FillDetectionsConfig) -> xr.Dataset:
    """Task: ``fill_suit`` with the limbs no observed corner holds posed on the detections no label claims
    (suit_corners, suit_labels; tasks/suit/limbs): the body fitted to the observed corners, each searched bone with
    too few of them turned onto the unclaimed detections, the corners matched there triangulated and the body
    fitted again with them (weight ``limb_confidence``); Eq. (8) fills the displacements of the observed corners
    alone, as ``fill_suit``."""
    observed_xyz = points["position"].transpose("frame", "corner", "xyz").values.astype(np.float64)
    face, bary = images["corner_face"].values, images["corner_bary"].values
    solver = _solver_body()
    body = fit_body(solver, observed_xyz, face, bary, config.body)
    placed = _limb_corners(solver, body, observed_xyz, images, corners, labels, config.limbs)
    extra = np.isfinite(placed).all(-1) & ~np.isfinite(observed_xyz).all(-1)
    if extra.any():  # the second fit: the first's phenotype held, the placed corners added
        held = replace(config.body, shape_sigma=config.refit_shape_sigma,
                       start=Phenotype(**dict(zip(PHENOTYPE_NAMES, np.clip(body.fit.phenotype, 0.0, 1.0).tolist()))))
        both = np.where(extra[..., None], placed, observed_xyz)
        body = fit_body(solver, both, face, bary, held, np.where(extra, config.limb_confidence, 1.0))
    return _filled(points, observed_xyz, body, images["cells"].values, config.fill)


def _limb_corners(solver: SolverBody, body, observed_xyz: np.ndarray, images: xr.Dataset, corners: xr.Dataset,
                  labels: xr.Dataset, config: LimbConfig) -> np.ndarray:
    """Corners of the searched limbs placed on the unclaimed detections (tasks/suit/limbs).  -> (frame, corner, 3)"""
    views = [str(v) for v in labels["view"].values]
    cameras = [camera_of(images, v) for v in views]
    lab = np.stack([labels["x"].transpose("view", "frame", "corner").values,
                    labels["y"].transpose("view", "frame", "corner").values], -1).astype(np.float64)
    det = corners.sel(view=views)
    det = np.stack([det["x"].transpose("view", "frame", "detection").values,
                    det["y"].transpose("view", "frame", "detection").values], -1).astype(np.float64)
    free = [unclaimed(det[v], lab[v], config.claimed_px) for v in range(len(views))]  # [view][frame]
    scene = [views_of(cameras, [free[v][f] for v in range(len(views))]) for f in range(len(observed_xyz))]
    mesh = solver.body
    corner_bone = mesh.vertex_bone[mesh.faces[images["corner_face"].values][:, 0]]
    limbs = limbs_of(mesh.bone_names, mesh.bone_parents, corner_bone, part_of_bone, config.bones)
    transforms = skinning_transforms(body.weights, body.bone_transforms)
    posed = repose(np.broadcast_to(body.rest, observed_xyz.shape), transforms)
    normals = (transforms[..., :3, :3] @ body.normals[..., None])[..., 0]
    observed = np.isfinite(observed_xyz).all(-1)
    xy = limb_pixels(posed, normals, body.heads, observed, limbs, scene, config)
    return limb_points(xy, cameras)


def _filled(points: xr.Dataset, observed_xyz: np.ndarray, body, cells: np.ndarray, config: FillConfig) -> xr.Dataset:
    """Eq. (8) on the observed corners' displacements from ``body``, reposed (``fill_suit``)."""
    transforms = skinning_transforms(body.weights, body.bone_transforms)  # (frame, corner, 4, 4)
    rest = np.broadcast_to(body.rest, observed_xyz.shape)
    displacement = unpose(observed_xyz, transforms) - rest  # Δṽ of the observed corners, NaN elsewhere
    laplacian = cotangent_laplacian(body.rest, cells)
    filled, observed = fill_sequence(displacement, laplacian, config)
    position = repose(rest + np.nan_to_num(filled, nan=0.0), transforms)
    position[observed] = observed_xyz[observed]  # the observations themselves, to the bit
    return xr.Dataset({"position": (("frame", "corner", "xyz"), position.astype(np.float32)),
                       "observed": (("frame", "corner"), observed)},
                      coords={"frame": points["frame"].values, "corner": points["corner"].values,
                              "xyz": np.array(["x", "y", "z"], dtype=object)},
                      attrs={"length_unit": "m", "up_axis": "Z", "fps": float(points.attrs["fps"]),
                             "phenotype": dict(zip(PHENOTYPE_NAMES, map(float, body.fit.phenotype)))})


def _solver_body() -> SolverBody:
    return reference_body()

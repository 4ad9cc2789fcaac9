"""The body model under the suit's corners (Chen, Park, Macit, Kavan 2021, §5): a skinned body fitted to the
observed corners, for hole filling (tasks/suit/fill) to unpose them into the rest pose and repose the filled ones.

The paper fits STAR, refined per actor; here the body is Anny, fitted as every system fits it (tasks/shared/place_fit:
key frames, the phenotype once per take, then every frame, on the house's Levenberg-Marquardt fitter): every
corner's place on the rest body is known, a point (face, barycentric) of ``MeshBody.faces``. A corner is skinned as
one point with its own weights, the barycentric blend of its face's vertices' Anny weights, so that
``fill.skinning_transforms`` / ``unpose`` / ``repose`` apply to it unchanged; this differs from blending the three
skinned vertices by a second-order term (well under a millimetre; the non-articulated displacements absorb it).

The result is in the rest body's own frame (feet at z = 0, as ``mesh_body``'s): rest corners and, per frame, each
bone's rest -> posed 4x4 transform [M_k | h_k - M_k r_k].
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mocapflow.tasks.shared import body_fit as lm
from mocapflow.tasks.shared.place_fit import PlaceFitConfig, PlaceFitError, fit_places
from mocapflow.tasks.shared.solver_body import BodyFit, SolverBody


class BodyFitError(ValueError):
    """Corners, places on the body or settings the suit's body fit cannot use."""


BodyFitConfig = PlaceFitConfig  # the suit's body fit is the house's (min_points: its fewest corners a frame)


@dataclass(frozen=True)
class SuitBody:
    fit: BodyFit  # local rotations (frame, bone, 3, 3), root (frame, 3), phenotype (6,)
    bone_transforms: np.ndarray  # (frame, bone, 4, 4) rest -> posed
    weights: np.ndarray  # (corner, bone) skinning weights
    rest: np.ndarray  # (corner, 3) rest positions on the fitted body, the frame of bone_transforms
    borrowed: np.ndarray  # (frame,) bool: posed from its neighbours (too few corners observed)
    heads: np.ndarray  # (frame, bone, 3) each bone's posed head
    normals: np.ndarray  # (corner, 3) unit normals of the corners' faces on the fitted rest body


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


def fit_body(body: SolverBody, points: np.ndarray, face: np.ndarray, barycentric: np.ndarray,
             config: BodyFitConfig = BodyFitConfig(), confidence: np.ndarray | None = None) -> SuitBody:
    """Fit Anny to a take's corners (§5, Chen et al. 2021; see the module's text).

    points (frame, corner, 3) NaN where unobserved; face (corner,) index into ``body.body.faces``; barycentric
    (corner, 2), the corner at (1-u-v) V0 + u V1 + v V2 of its face on the rest body; confidence (frame, corner)
    >= 0 each point's weight (1 where not given).
    """
    points = np.asarray(points, np.float64)
    face, barycentric = np.asarray(face), np.asarray(barycentric, np.float64)
    _check_places(body, points, face, barycentric)
    places = lm.Places.of_faces(body.body, face, barycentric)
    try:
        placed = fit_places(body, points, places, config, confidence)
    except PlaceFitError as e:
        raise BodyFitError(f"the suit's corners: {e}") from e
    transforms, rest_corners, heads, vertices = _rest_frame(body, placed.fit,
                                                            lm.rest_of(body, placed.fit.phenotype, (places,)))
    return SuitBody(fit=placed.fit, bone_transforms=transforms, weights=placed.weights, rest=rest_corners,
                    borrowed=~placed.fitted, heads=heads, normals=face_normals(vertices, body.body.faces[face]))


def face_normals(vertices: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """Unit normals of triangles (counter-clockwise seen from outside).  vertices (vertex, 3), triangles (n, 3)
    -> (n, 3)"""
    p = vertices[triangles]
    n = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    return n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)


def _rest_frame(body: SolverBody, fit: BodyFit, rest: lm.Rest):
    """Bone transforms (frame, bone, 4, 4) and rest corners (corner, 3) in the rest body's frame, feet at z = 0;
    the posed heads (frame, bone, 3) and the rest vertices (vertex, 3)."""
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
    return transforms, (rest.points[0] + lift).numpy(), heads.numpy(), vertices.numpy()

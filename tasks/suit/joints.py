"""The 20 template joints from the suit's corners: the suit gives a surface, not a skeleton.

Each joint is carried by the corners nearest to it on the rest body (the body the filling fitted, tasks/suit/fill.py):
per frame, the similarity that best maps those rest corners onto their filled positions (Umeyama 1991, Eq. (40)-(42):
rotation, scale and translation in the least-squares sense) moves the joint's rest position with them. Not a stage
of Chen et al. 2021 (their output is the suit's surface); it lets the suit be scored on the joints like the others.
"""

from __future__ import annotations

import numpy as np

NEIGHBOURS = 40  # corners carrying each joint
MIN_POINTS = 8  # fewer given corners: the joint is not given that frame
SCALE_RANGE = (0.8, 1.25)  # the local scale a fit may take (a bent joint's skin stretches, it does not double)


def rest_corners(vertices: np.ndarray, faces: np.ndarray, corner_face: np.ndarray, corner_bary: np.ndarray) -> np.ndarray:
    """Corners on a rest mesh: (1-u-v) v0 + u v1 + v v2 of their face.  -> (corner, 3)"""
    tri = vertices[faces[corner_face]]  # (corner, 3, 3)
    u, v = corner_bary[:, :1], corner_bary[:, 1:]
    return (1 - u - v) * tri[:, 0] + u * tri[:, 1] + v * tri[:, 2]


def joint_neighbourhoods(rest: np.ndarray, rest_joints: np.ndarray, k: int = NEIGHBOURS) -> np.ndarray:
    """The ``k`` rest corners nearest each rest joint.  rest (corner, 3), rest_joints (joint, 3) -> (joint, k)"""
    distance = np.linalg.norm(rest[None] - rest_joints[:, None], axis=-1)
    return np.argsort(distance, axis=1)[:, :k]


def similarity(source: np.ndarray, target: np.ndarray) -> tuple[np.ndarray, float, np.ndarray]:
    """(R, s, t) minimising sum |s R source + t - target|^2, Eq. (40)-(42), Umeyama 1991.  (n, 3) x 2"""
    mu_s, mu_t = source.mean(0), target.mean(0)
    a, b = source - mu_s, target - mu_t
    u, d, vt = np.linalg.svd(b.T @ a / len(a))
    sign = np.diag([1.0, 1.0, np.sign(np.linalg.det(u @ vt))])
    rotation = u @ sign @ vt
    variance = (a ** 2).sum() / len(a)
    scale = float(np.clip(np.trace(np.diag(d) @ sign) / max(variance, 1e-12), *SCALE_RANGE))
    return rotation, scale, mu_t - scale * rotation @ mu_s


def joints_from_corners(corners: np.ndarray, rest: np.ndarray, rest_joints: np.ndarray, neighbours: np.ndarray,
                        min_points: int = MIN_POINTS) -> np.ndarray:
    """Joints per frame from corners (frame, corner, 3) m, NaN where missing -> (frame, joint, 3), NaN where fewer
    than ``min_points`` of a joint's neighbours are given."""
    out = np.full((len(corners), len(rest_joints), 3), np.nan)
    for f, frame in enumerate(corners):
        for j, near in enumerate(neighbours):
            given = np.isfinite(frame[near]).all(-1)
            if given.sum() < min_points:
                continue
            rotation, scale, shift = similarity(rest[near[given]], frame[near[given]])
            out[f, j] = scale * rotation @ rest_joints[j] + shift
    return out

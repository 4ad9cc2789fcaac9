"""Rotations and forward kinematics for every articulated body (the template, BVH skeletons, solved poses).

A skeleton is a parent index per joint (-1 for the root; one root). Each joint's local rotation is
relative to its parent's frame, and its offset is the joint's position in the parent's frame; world
rotations and positions follow down the tree, one vectorized step per depth.
"""

from __future__ import annotations

import functools

import numpy as np


def cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """a x b over the last axis, broadcast (np.cross's axis handling costs more than the product here)."""
    return np.stack([a[..., 1] * b[..., 2] - a[..., 2] * b[..., 1],
                     a[..., 2] * b[..., 0] - a[..., 0] * b[..., 2],
                     a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]], axis=-1)


def skew(v: np.ndarray) -> np.ndarray:
    """Cross-product matrices [v]x.  (..., 3) -> (..., 3, 3)"""
    k = np.zeros(v.shape[:-1] + (3, 3))
    k[..., 0, 1], k[..., 0, 2], k[..., 1, 2] = -v[..., 2], v[..., 1], -v[..., 0]
    return k - np.swapaxes(k, -1, -2)


def rodrigues(rotvec: np.ndarray) -> np.ndarray:
    """Rotation matrices of rotation vectors.  (..., 3) -> (..., 3, 3)"""
    theta = np.linalg.norm(rotvec, axis=-1)[..., None, None]  # (..., 1, 1)
    k = rotvec / np.where(theta > 1e-12, theta, 1.0)[..., 0]  # unit axis (zero for no rotation)
    kkt = k[..., :, None] * k[..., None, :]
    return np.cos(theta) * np.eye(3) + np.sin(theta) * skew(k) + (1 - np.cos(theta)) * kkt  # Rodrigues' formula


def right_jacobian(rotvec: np.ndarray) -> np.ndarray:
    """J_r(θ) with exp([θ + dθ]x) ≈ exp([θ]x) exp([J_r dθ]x).  (..., 3) -> (..., 3, 3)

    J_r = I - (1 - cos φ) / φ² [θ]x + (φ - sin φ) / φ³ [θ]x², φ = |θ|  (J_r -> I - [θ]x / 2 as φ -> 0)
    """
    phi = np.linalg.norm(rotvec, axis=-1)[..., None, None]
    small = phi < 1e-6
    p = np.where(small, 1.0, phi)
    a = np.where(small, 0.5, (1 - np.cos(p)) / p**2)
    b = np.where(small, 1.0 / 6.0, (p - np.sin(p)) / p**3)
    k = skew(rotvec)
    return np.eye(3) - a * k + b * (k @ k)


def rigid_fit(source: np.ndarray, target: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rotation and translation taking ``source`` onto ``target`` in the least-squares sense (Kabsch). (n, 3) x 2"""
    mu_s, mu_t = source.mean(0), target.mean(0)
    u, _, vt = np.linalg.svd((source - mu_s).T @ (target - mu_t))
    d = np.sign(np.linalg.det(vt.T @ u.T))
    r = vt.T @ np.diag([1.0, 1.0, d]) @ u.T
    return r, mu_t - r @ mu_s


# A Y-up file's axes onto the project's Z up, by a proper rotation about x: (x, y, z) -> (x, -z, y).
Y_UP_TO_Z_UP = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])


class SkeletonError(ValueError):
    """Parent indices that do not form one tree."""


@functools.lru_cache(maxsize=32)
def _by_depth(parents: tuple[int, ...]) -> tuple[int, tuple[tuple[np.ndarray, np.ndarray], ...]]:
    depth = np.full(len(parents), -1)
    roots = [j for j, p in enumerate(parents) if p < 0]
    if len(roots) != 1:
        raise SkeletonError(f"a skeleton has one root (parent -1), these parent indices have {len(roots)}: {list(parents)}")
    depth[roots[0]] = 0
    for _ in parents:  # at most one pass per level
        todo = [j for j, p in enumerate(parents) if depth[j] < 0 and p >= 0 and depth[p] >= 0]
        if not todo:
            break
        depth[todo] = depth[[parents[j] for j in todo]] + 1
    if (depth < 0).any():
        raise SkeletonError(f"parent indices {list(parents)} hold a cycle or point outside the skeleton; "
                            "each joint needs a chain of parents up to the root")
    steps = tuple((np.flatnonzero(depth == d), np.asarray(parents)[depth == d]) for d in range(1, depth.max() + 1))
    return roots[0], steps


def world_rotations(local_rot: np.ndarray, parents) -> np.ndarray:
    """World rotations of every joint.  (batch, joint, 3, 3) local rotations, (joint,) parents -> (batch, joint, 3, 3)"""
    root, steps = _by_depth(tuple(int(p) for p in parents))
    rot = np.empty_like(local_rot)
    rot[:, root] = local_rot[:, root]
    for joints, up in steps:
        rot[:, joints] = rot[:, up] @ local_rot[:, joints]
    return rot


def local_rotations(world: np.ndarray, parents) -> np.ndarray:
    """Each joint's rotation relative to its parent's (the inverse of world_rotations).
    (batch, joint, 3, 3) world rotations, (joint,) parents -> (batch, joint, 3, 3)"""
    parents = np.asarray(parents)
    local = world.copy()
    has = parents >= 0
    local[:, has] = np.swapaxes(world[:, parents[has]], -1, -2) @ world[:, has]
    return local


def forward_kinematics(local_rot: np.ndarray, root_pos: np.ndarray, offsets: np.ndarray,
                       parents) -> tuple[np.ndarray, np.ndarray]:
    """World rotations and positions of every joint.

    local_rot (batch, joint, 3, 3) relative to the parent frame; root_pos (batch, 3) the root's world position;
    offsets (joint, 3) or (batch, joint, 3) each joint's position in its parent's frame; parents (joint,)
    -> (batch, joint, 3, 3) world rotations, (batch, joint, 3) world positions
    """
    root, steps = _by_depth(tuple(int(p) for p in parents))
    rot, pos = np.empty_like(local_rot), np.empty(local_rot.shape[:-1])
    rot[:, root], pos[:, root] = local_rot[:, root], root_pos
    per_frame = offsets.ndim == 3  # (batch, joint, 3): offsets that change per frame (BVH position channels)
    for joints, up in steps:
        rot[:, joints] = rot[:, up] @ local_rot[:, joints]
        if per_frame:
            pos[:, joints] = pos[:, up] + np.einsum("bkij,bkj->bki", rot[:, up], offsets[:, joints])
        else:
            pos[:, joints] = pos[:, up] + (rot[:, up] @ offsets[joints][..., None])[..., 0]
    return rot, pos

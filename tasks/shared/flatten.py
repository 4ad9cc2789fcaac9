"""Flattening a piece of surface onto the plane with little stretch: how a garment's panel is cut from the body.

``lscm`` is the least-squares conformal map (Lévy et al. 2002) in its Dirichlet-minus-area form (Mullen et al.
2008): the cotangent Dirichlet energy of (u, v) less the signed area of the flattened piece, two boundary vertices
pinned. It keeps angles but not areas. ``arap`` (Liu et al. 2008, "A local/global approach to mesh
parameterization") starts from it and alternates the best rotation of each triangle (local) with one sparse solve
for every vertex (global), which brings every triangle near its own size: a panel that can be printed flat and
stretched onto the body.

Both take one piece: ``faces`` (face, 3) counter-clockwise seen from outside, indexing ``vertices`` (vertex, 3) of
that piece only, with at least one boundary edge (a closed surface cannot be flattened without a cut).
"""

from __future__ import annotations

import numpy as np
from scipy import sparse
from scipy.sparse import linalg as splinalg


class FlattenError(ValueError):
    """A piece of surface that cannot be flattened."""


def local_frames(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Each triangle in a 2D frame of its own plane, isometric: corner 0 at the origin, corner 1 on +x.
    -> (face, 3, 2)"""
    p = vertices[faces]
    e1, e2 = p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]
    l1 = np.linalg.norm(e1, axis=1)
    if (l1 <= 0).any():
        raise FlattenError(f"{int((l1 <= 0).sum())} triangles have an edge of length zero; weld or drop them first")
    x = e1 / l1[:, None]
    n = np.cross(e1, e2)
    y = np.cross(n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300), x)
    out = np.zeros((len(faces), 3, 2))
    out[:, 1, 0] = l1
    out[:, 2] = np.column_stack([np.einsum("ij,ij->i", e2, x), np.einsum("ij,ij->i", e2, y)])
    return out


def half_cotangents(frames: np.ndarray) -> np.ndarray:
    """Half the cotangent of each triangle's angle at corner k, the weight of the edge opposite it.
    frames (face, 3, 2) -> (face, 3)"""
    a = np.roll(frames, -1, axis=1) - frames  # corner k -> k + 1
    b = np.roll(frames, -2, axis=1) - frames  # corner k -> k + 2
    dot = np.einsum("fki,fki->fk", a, b)
    cross = np.abs(a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0])
    return 0.5 * dot / np.maximum(cross, 1e-300)


def cotangent_laplacian(faces: np.ndarray, weights: np.ndarray, n: int) -> sparse.csc_matrix:
    """L with L_ij = -w_ij summed over the triangles sharing edge ij, rows summing to zero: the quadratic form of
    the Dirichlet energy, sum over triangles of area x |grad u|^2 = u^T L u.  weights (face, 3) from
    ``half_cotangents``."""
    i, j = np.roll(faces, -1, axis=1).ravel(), np.roll(faces, -2, axis=1).ravel()  # edge opposite corner k
    w = weights.ravel()
    off = sparse.coo_matrix((-w, (i, j)), (n, n))
    off = off + off.T
    return (off - sparse.diags(np.asarray(off.sum(axis=1)).ravel())).tocsc()


def boundary_edges(faces: np.ndarray) -> np.ndarray:
    """Directed edges (a, b) of the piece's boundary, oriented as its faces run.  -> (edge, 2)"""
    edges = np.stack([faces, np.roll(faces, -1, axis=1)], axis=2).reshape(-1, 2)
    n = int(faces.max()) + 1
    key = edges[:, 0].astype(np.int64) * n + edges[:, 1]
    back = edges[:, 1].astype(np.int64) * n + edges[:, 0]
    return edges[~np.isin(key, back)]


def lscm(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """The least-squares conformal map of a piece, orientation kept (faces counter-clockwise in the plane too),
    at the size where its two farthest boundary vertices lie as far apart as on the surface.  -> (vertex, 2)"""
    n = len(vertices)
    rim = boundary_edges(faces)
    if not len(rim):
        raise FlattenError(f"a piece of {len(faces)} faces has no boundary; cut it open before flattening")
    L = cotangent_laplacian(faces, half_cotangents(local_frames(vertices, faces)), n)
    a, b = rim[:, 0], rim[:, 1]
    # Signed area of the flat piece, 1/2 sum over boundary edges of (u_a v_b - u_b v_a) = u^T C v.
    C = sparse.coo_matrix((np.r_[0.5 * np.ones(len(a)), -0.5 * np.ones(len(a))], (np.r_[a, b], np.r_[b, a])), (n, n))
    Q = sparse.bmat([[L, -C], [-C.T, L]]).tocsc()  # 1/2 x^T Q x = Dirichlet energy - area (Mullen et al. 2008)
    ends = _farthest_pair(vertices, np.unique(rim))
    pinned = np.array([ends[0], ends[1], n + ends[0], n + ends[1]])
    x_pinned = np.array([0.0, np.linalg.norm(vertices[ends[1]] - vertices[ends[0]]), 0.0, 0.0])
    free = np.setdiff1d(np.arange(2 * n), pinned)
    x = np.zeros(2 * n)
    x[pinned] = x_pinned
    x[free] = splinalg.spsolve(Q[free][:, free], -Q[free][:, pinned] @ x_pinned)
    return np.column_stack([x[:n], x[n:]])


def arap(vertices: np.ndarray, faces: np.ndarray, start: np.ndarray, iterations: int = 40) -> np.ndarray:
    """As-rigid-as-possible flattening from ``start`` (vertex, 2): each triangle's best rotation of its own shape,
    then every vertex in one least-squares solve, ``iterations`` times.  -> (vertex, 2)"""
    n = len(vertices)
    frames = local_frames(vertices, faces)
    w = half_cotangents(frames)
    L = cotangent_laplacian(faces, w, n)
    solve = splinalg.splu(L[1:, 1:].tocsc()).solve  # vertex 0 held where it is: the map's translation
    i, j = np.roll(faces, -1, axis=1), np.roll(faces, -2, axis=1)  # (face, 3) the edge opposite corner k
    rest = np.roll(frames, -1, axis=1) - np.roll(frames, -2, axis=1)  # (face, 3, 2) x_i - x_j
    uv = np.array(start, float)
    for _ in range(iterations):
        flat = uv[i] - uv[j]  # (face, 3, 2)
        cov = np.einsum("fk,fka,fkb->fab", w, flat, rest)  # sum_k w (u_i - u_j)(x_i - x_j)^T
        U, _, Vt = np.linalg.svd(cov)
        det = np.sign(np.linalg.det(U @ Vt))
        U[:, :, 1] *= det[:, None]  # a rotation, never a reflection
        R = U @ Vt  # (face, 2, 2)
        edge = w[..., None] * np.einsum("fab,fkb->fka", R, rest)  # (face, 3, 2)
        rhs = np.zeros((n, 2))
        np.add.at(rhs, i.ravel(), edge.reshape(-1, 2))
        np.add.at(rhs, j.ravel(), -edge.reshape(-1, 2))
        rhs = rhs[1:] - L[1:, :1].toarray() * uv[0]
        uv[1:] = np.column_stack([solve(rhs[:, 0]), solve(rhs[:, 1])])
    return uv


def stretch(vertices: np.ndarray, faces: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Each triangle's area in the plane over its area on the surface.  -> (face,)"""
    p = vertices[faces]
    area3 = 0.5 * np.linalg.norm(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), axis=1)
    t = uv[faces]
    e1, e2 = t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]
    return 0.5 * (e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]) / np.maximum(area3, 1e-300)


def _farthest_pair(vertices: np.ndarray, candidates: np.ndarray) -> tuple[int, int]:
    """Two of ``candidates`` far apart: the farthest from the first, then the farthest from that one."""
    a = candidates[np.argmax(np.linalg.norm(vertices[candidates] - vertices[candidates[0]], axis=1))]
    b = candidates[np.argmax(np.linalg.norm(vertices[candidates] - vertices[a], axis=1))]
    return int(a), int(b)

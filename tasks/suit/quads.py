"""Candidate quads (Chen et al. 2021, §3.2 "Quad detection"): every 4-set of detected corners that could be a square
of the suit, and each warped to a square crop for the code networks.

A square of the board shows as four detections, each the nearest-ish neighbour of two others. For every detection
``c`` and every pair (a, b) of its ``neighbours`` nearest detections that meet at ``c`` at an angle in
[``min_angle``, ``max_angle``], the fourth corner is predicted at a + b - c (a parallelogram) and the detection
nearest to it, within ``fourth_tolerance`` of the mean edge, closes the quad. The early filters of the paper follow:
a convex quad, every inner angle within the bounds, every edge within [``min_edge_px``, ``max_edge_px``] and at
most ``max_edge_ratio`` times the shortest. Each quad is listed once, clockwise in the image (x right, y down),
starting at its lowest detection index.

A last early filter looks at the image: a white square of the board is brighter just inside each of its four edges
than just outside (``edge_contrast``: at four of five points along each edge at least). Black squares, and the
parallelograms that cut across squares (their diagonal edges have the same colour on both sides), fall here before
the networks see them.

``warp_quads`` maps each quad by a homography onto a ``size`` x ``size`` crop (104 x 104, §3.2), the quad's four
corners on a square inset by ``inset`` so the crop also shows the square's surroundings: quad vertex 0 at the
crop's top-left, then clockwise.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from scipy.spatial import cKDTree

CROP = 104  # §3.2, Chen et al. 2021: each candidate quad warped to 104 x 104


class QuadError(ValueError):
    """Corners or settings the quad search cannot use."""


@dataclass(frozen=True)
class QuadConfig:
    neighbours: int = 8  # nearest detections tried as a corner's edge partners
    min_angle: float = 45.0  # §3.2: inner angles within [45, 135] degrees
    max_angle: float = 135.0
    min_edge_px: float = 5.0
    max_edge_px: float = 150.0
    max_edge_ratio: float = 2.5  # longest edge over shortest
    fourth_tolerance: float = 0.3  # of the mean of the two edges, how far the 4th detection may be from a + b - c
    min_contrast: float = 8.0  # grey levels a white square is brighter inside each edge than outside, at least
    capacity: int = 4096  # most quads kept per image (the stage's padding)

    def __post_init__(self):
        if not 0 < self.min_angle < 90 < self.max_angle < 180:
            raise QuadError(f"need 0 < min_angle < 90 < max_angle < 180, got {self.min_angle}, {self.max_angle}")
        if not 0 < self.min_edge_px < self.max_edge_px or self.max_edge_ratio < 1:
            raise QuadError(f"edge bounds [{self.min_edge_px}, {self.max_edge_px}] px and ratio {self.max_edge_ratio} "
                            "must satisfy 0 < min < max and ratio >= 1")
        if self.neighbours < 2 or self.capacity < 1 or not 0 < self.fourth_tolerance < 1:
            raise QuadError(f"neighbours >= 2 (got {self.neighbours}), capacity >= 1 (got {self.capacity}) and "
                            f"fourth_tolerance in (0, 1) (got {self.fourth_tolerance})")


def candidate_quads(image: np.ndarray, xy: np.ndarray, config: QuadConfig = QuadConfig()) -> np.ndarray:
    """image (y, x) uint8, xy (n, 2) detections (x, y) -> (q, 4) int detection indices, clockwise in the image, each
    quad once, the white-looking ones."""
    quads = corner_quads(xy, config)
    if len(quads):
        quads = quads[edge_contrast(image, np.asarray(xy, np.float64)[quads]) >= config.min_contrast]
    return quads[:config.capacity]


def corner_quads(xy: np.ndarray, config: QuadConfig = QuadConfig()) -> np.ndarray:
    """The geometric part of :func:`candidate_quads`: xy (n, 2) -> (q, 4), every quad passing the shape filters."""
    xy = np.asarray(xy, np.float64)
    n = len(xy)
    if n < 4:
        return np.zeros((0, 4), np.int64)
    k = min(config.neighbours, n - 1)
    tree = cKDTree(xy)
    dist, nb = tree.query(xy, k=k + 1)
    dist, nb = dist[:, 1:], nb[:, 1:]  # (n, k) without the point itself
    ia, ib = np.triu_indices(k, 1)
    c = np.repeat(np.arange(n), len(ia))  # every corner with every pair of its neighbours
    a, b = nb[:, ia].ravel(), nb[:, ib].ravel()
    ok = ((dist[:, ia] <= config.max_edge_px) & (dist[:, ib] <= config.max_edge_px)
          & (dist[:, ia] >= config.min_edge_px) & (dist[:, ib] >= config.min_edge_px)).ravel()
    c, a, b = c[ok], a[ok], b[ok]
    ea, eb = xy[a] - xy[c], xy[b] - xy[c]
    cos = np.einsum("ij,ij->i", ea, eb) / (np.linalg.norm(ea, axis=1) * np.linalg.norm(eb, axis=1))
    lo, hi = np.cos(np.radians(config.max_angle)), np.cos(np.radians(config.min_angle))
    ok = (cos >= lo) & (cos <= hi)
    c, a, b = c[ok], a[ok], b[ok]
    predicted = xy[a] + xy[b] - xy[c]  # the parallelogram's fourth corner
    tol = config.fourth_tolerance * 0.5 * (np.linalg.norm(xy[a] - xy[c], axis=1) + np.linalg.norm(xy[b] - xy[c], axis=1))
    dd, d = tree.query(predicted)
    ok = (dd <= tol) & (d != a) & (d != b) & (d != c)
    quads = np.column_stack([c[ok], a[ok], d[ok], b[ok]])  # c -> a -> d -> b goes round the quad
    if not len(quads):
        return np.zeros((0, 4), np.int64)
    quads = unique_rows(_canonical(quads, xy), n)
    return quads[quad_ok(xy[quads], config)]


def unique_rows(quads: np.ndarray, n: int) -> np.ndarray:
    """``np.unique(quads, axis=0)`` for rows of indices below n: sorted, each once, through one int64 key per row
    (a tenth of the time; rows sort alike either way).  quads (q, 4) -> (u, 4)"""
    quads = np.asarray(quads, np.int64)
    if n ** 4 >= 2 ** 63:
        return np.unique(quads, axis=0)
    key = np.unique(((quads[:, 0] * n + quads[:, 1]) * n + quads[:, 2]) * n + quads[:, 3])
    out = np.empty((len(key), 4), np.int64)
    for i in range(3, -1, -1):
        key, out[:, i] = np.divmod(key, n)
    return out


def edge_contrast(image: np.ndarray, points: np.ndarray) -> np.ndarray:
    """How much brighter each quad is just inside its edges than just outside: the smallest over its four edges of
    the second smallest of five differences along the edge (one may fall on a glyph's stroke), sampled 15 % of the
    edge's length (at least 1.5 px) to either side.
    image (y, x), points (q, 4, 2) clockwise -> (q,) grey levels"""
    edges = np.roll(points, -1, axis=1) - points  # (q, 4, 2)
    length = np.linalg.norm(edges, axis=2, keepdims=True)
    inward = np.stack([-edges[..., 1], edges[..., 0]], axis=-1) / np.maximum(length, 1e-9)  # right of a clockwise edge
    step = np.maximum(0.15 * length, 1.5)[..., None]  # (q, 4, 1, 1)
    t = np.linspace(0.2, 0.8, 5)[None, None, :, None]
    along = points[:, :, None, :] + t * edges[:, :, None, :]  # (q, 4, 5, 2)
    inside = _bilinear(image, along + step * inward[:, :, None, :])
    outside = _bilinear(image, along - step * inward[:, :, None, :])
    return np.partition(inside - outside, 1, axis=2)[:, :, 1].min(axis=1)  # one sample may fall on a glyph


def _bilinear(image: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """image values at sub-pixel (x, y), clamped at the border.  xy (..., 2) -> (...)"""
    h, w = image.shape
    x = np.clip(xy[..., 0], 0, w - 1.001)
    y = np.clip(xy[..., 1], 0, h - 1.001)
    x0, y0 = np.floor(x).astype(np.int64), np.floor(y).astype(np.int64)
    fx, fy = x - x0, y - y0
    top = image[y0, x0] * (1 - fx) + image[y0, x0 + 1] * fx  # the grey levels gathered, not the image converted
    bottom = image[y0 + 1, x0] * (1 - fx) + image[y0 + 1, x0 + 1] * fx
    return top * (1 - fy) + bottom * fy


def _canonical(quads: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """Each quad clockwise in the image (positive shoelace area with y down), starting at its lowest index."""
    p = xy[quads]  # (q, 4, 2)
    area = np.sum(p[:, :, 0] * np.roll(p[:, :, 1], -1, axis=1) - np.roll(p[:, :, 0], -1, axis=1) * p[:, :, 1], axis=1)
    quads = np.where((area < 0)[:, None], quads[:, ::-1], quads)
    start = np.argmin(quads, axis=1)
    return np.take_along_axis(quads, (start[:, None] + np.arange(4)[None]) % 4, axis=1)


def quad_ok(points: np.ndarray, config: QuadConfig) -> np.ndarray:
    """The paper's early filters on clockwise quads.  points (q, 4, 2) -> (q,) bool: convex, every inner angle in
    [min_angle, max_angle], every edge within the bounds and the ratio."""
    edges = np.roll(points, -1, axis=1) - points  # edge i: vertex i -> i + 1
    length = np.linalg.norm(edges, axis=2)
    prev = np.roll(edges, 1, axis=1)  # the edge arriving at vertex i
    cross = prev[..., 0] * edges[..., 1] - prev[..., 1] * edges[..., 0]  # > 0 at every vertex of a clockwise quad
    cos = -np.einsum("qkd,qkd->qk", prev, edges) / np.maximum(np.roll(length, 1, axis=1) * length, 1e-12)
    angle = np.degrees(np.arccos(np.clip(cos, -1, 1)))
    return ((cross > 0).all(axis=1) & (angle >= config.min_angle).all(axis=1) & (angle <= config.max_angle).all(axis=1)
            & (length.min(axis=1) >= config.min_edge_px) & (length.max(axis=1) <= config.max_edge_px)
            & (length.max(axis=1) <= config.max_edge_ratio * length.min(axis=1)))


def crop_square(size: int = CROP, inset: float = 0.25) -> np.ndarray:
    """Where a quad's corners land in its crop: vertex 0 top-left, then clockwise; pixel centres at integers.
    -> (4, 2) float32"""
    lo, hi = inset * size / 2 - 0.5, size - inset * size / 2 - 0.5
    return np.array([(lo, lo), (hi, lo), (hi, hi), (lo, hi)], np.float32)


def quad_homographies(points: np.ndarray, size: int = CROP, inset: float = 0.25) -> np.ndarray:
    """Homographies from each crop to its image: crop (u, v, 1) -> image.  points (q, 4, 2) -> (q, 3, 3)"""
    dst = crop_square(size, inset)
    return np.stack([cv2.getPerspectiveTransform(dst, p.astype(np.float32)) for p in points]).reshape(-1, 3, 3)


def warp_quads(image: np.ndarray, points: np.ndarray, size: int = CROP, inset: float = 0.25) -> np.ndarray:
    """Each quad of ``image`` (y, x) uint8 warped onto a size x size crop (bilinear, border grey).
    points (q, 4, 2) clockwise image corners -> (q, size, size) uint8"""
    if image.ndim != 2:
        raise QuadError(f"warp_quads needs a grey (y, x) image, got shape {image.shape}")
    out = np.empty((len(points), size, size), np.uint8)
    if not len(points):
        return out
    h = quad_homographies(points, size, inset)
    for i, m in enumerate(h):
        out[i] = cv2.warpPerspective(image, m, (size, size), flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                                     borderMode=cv2.BORDER_CONSTANT, borderValue=128)
    return out


# ---------------------------------------------------------------------------------------------------- the stage

def find_quads(images, corners, config: QuadConfig):
    """Task: suit_quads of every view and frame from suit_images and suit_corners (§3.2)."""
    import xarray as xr

    views, frames = images["view"].values, images["frame"].values
    out = np.full((len(views), len(frames), config.capacity, 4), -1, np.int32)
    for v in range(len(views)):
        for f in range(len(frames)):
            xy = np.column_stack([corners["x"].values[v, f], corners["y"].values[v, f]])
            n = int(np.isfinite(xy[:, 0]).sum())  # detections are packed at the front
            quads = candidate_quads(images["image"].values[v, f], xy[:n], config)
            out[v, f, :len(quads)] = quads
    return xr.Dataset({"detections": (("view", "frame", "quad", "k"), out)}, coords={"view": views, "frame": frames})

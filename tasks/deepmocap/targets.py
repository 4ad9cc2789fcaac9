"""Crops, augmentation and training targets of the two-stream FCN (DeepMoCap §3.3.1-3.3.2, §5.1.1).

Every image the network sees is a square crop around the subject: the box of the reflector regions
(the straps and patches cover the body from head to feet), widened by a margin. Training draws the
crop's scale, rotation, flip and shift at random (§5.1.1); inference uses the nominal crop. The
targets live on the network's output grid, whose cell ``j`` covers input pixels ``[s·j, s·j + s)``
for stride ``s``, so a point at input pixel ``x`` sits at cell coordinate ``(x - (s - 1) / 2) / s``.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from mocapflow.tasks.shared.labels import mirrored
from mocapflow.tasks.shared.reflectors import REFLECTOR_NAMES


FLIP_ORDER = np.array([REFLECTOR_NAMES.index(mirrored(n)) for n in REFLECTOR_NAMES])  # channel r <- FLIP_ORDER[r]


@dataclass(frozen=True)
class CropJitter:
    """One crop's random draw (§5.1.1); the identity is the nominal inference crop."""

    scale: float = 1.0
    rotation_deg: float = 0.0
    flip: bool = False
    shift: tuple[float, float] = (0.0, 0.0)  # fraction of the crop side


def draw_jitter(rng: np.random.Generator, *, scale=(0.6, 1.1), rotation_deg=40.0, shift=0.1) -> CropJitter:
    return CropJitter(scale=float(rng.uniform(*scale)), rotation_deg=float(rng.uniform(-rotation_deg, rotation_deg)),
                      flip=bool(rng.random() < 0.5), shift=tuple(float(v) for v in rng.uniform(-shift, shift, 2)))


@dataclass(frozen=True)
class BoxRule:
    """Which reflector regions define the subject box (see subject_box)."""

    min_area: int = 3
    speck_area: int = 0
    link_px: float = 0.0


def subject_box(blob_id: np.ndarray, blob_area: np.ndarray, rule: BoxRule = BoxRule()) -> np.ndarray:
    """(x0, y0, x1, y1) around the reflector regions of at least ``rule.min_area`` pixels; the whole image if none.

    A speck, a region under ``rule.speck_area`` pixels whose centre lies farther than ``rule.link_px`` from every
    other region's (a reflective object in the room, sensor glare), is left out: it would stretch the box over the
    image. A reflector on the body has a neighbour within reach; a large isolated region stays in."""
    h, w = blob_id.shape  # (y, x)
    keep = np.concatenate([[False], np.asarray(blob_area) >= rule.min_area])  # index 0: no blob
    ys, xs = np.nonzero(blob_id)
    labels = blob_id[ys, xs]
    if rule.speck_area > 0 and rule.link_px > 0 and keep.sum() > 1:
        small = np.concatenate([[0], np.asarray(blob_area)]) < rule.speck_area
        keep &= ~_specks(xs, ys, labels, keep, small, rule.link_px)
    inside = keep[labels]
    if not inside.any():
        return np.array([0.0, 0.0, w - 1.0, h - 1.0], np.float32)
    xs, ys = xs[inside], ys[inside]
    return np.array([xs.min(), ys.min(), xs.max(), ys.max()], np.float32)


def _specks(xs: np.ndarray, ys: np.ndarray, labels: np.ndarray, keep: np.ndarray, small: np.ndarray,
            link_px: float) -> np.ndarray:
    """(blob,) bool: the kept regions that are ``small`` and whose nearest other kept region's centre is farther
    than ``link_px``.  xs, ys, labels (pixel,): every region pixel and its region"""
    from scipy.spatial import cKDTree

    pixels = np.bincount(labels, minlength=len(keep)).astype(np.float64)
    ids = np.flatnonzero(keep & (pixels > 0))
    out = np.zeros_like(keep)
    if len(ids) < 2:
        return out
    centre = np.stack([np.bincount(labels, xs, len(keep))[ids], np.bincount(labels, ys, len(keep))[ids]], 1) \
        / pixels[ids, None]  # (region, 2) x, y
    nearest, _ = cKDTree(centre).query(centre, k=2)  # itself, then its nearest neighbour
    out[ids] = small[ids] & (nearest[:, 1] > link_px)
    return out


def crop_affine(box: np.ndarray, *, size: int, margin: float, min_side: float,
                jitter: CropJitter = CropJitter()) -> np.ndarray:
    """2x3 affine mapping image pixels to crop pixels: the box's centre to the crop's, its long side
    times ``margin`` to ``size * jitter.scale`` pixels, rotated and flipped about the crop's centre."""
    x0, y0, x1, y1 = (float(v) for v in box)
    side = max(x1 - x0, y1 - y0, min_side) * margin
    centre = np.array([(x0 + x1) / 2, (y0 + y1) / 2]) + np.asarray(jitter.shift) * side
    zoom = size * jitter.scale / side
    theta = np.radians(jitter.rotation_deg)
    linear = zoom * np.array([[np.cos(theta), -np.sin(theta)], [np.sin(theta), np.cos(theta)]])
    if jitter.flip:
        linear = np.array([[-1.0, 0.0], [0.0, 1.0]]) @ linear
    half = (size - 1) / 2.0
    return np.hstack([linear, (np.array([half, half]) - linear @ centre)[:, None]])


def invert_affine(m: np.ndarray) -> np.ndarray:
    return cv2.invertAffineTransform(np.asarray(m, np.float64))


def apply_affine(m: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Map points (..., 2) through the 2x3 affine ``m``."""
    return points @ m[:, :2].T + m[:, 2]


def warp_depth(image: np.ndarray, m: np.ndarray, size: int) -> np.ndarray:
    """I_CD into the crop (outside the image: black, like invalid depth).  (y, x, 3) -> (size, size, 3)"""
    return cv2.warpAffine(image, m, (size, size), flags=cv2.INTER_LINEAR, borderValue=(0, 0, 0))


def warp_flow(image: np.ndarray, m: np.ndarray, size: int) -> np.ndarray:
    """I_F into the crop, its x/y motion channels turned with the crop (a flip negates x motion), so a
    rotated or mirrored sample shows motion as that camera would (128 = still, outside the image too)."""
    out = cv2.warpAffine(image, m, (size, size), flags=cv2.INTER_LINEAR, borderValue=(128, 128, 128))
    linear = m[:, :2] / np.sqrt(abs(np.linalg.det(m[:, :2])))  # a rotation, or a rotation and a flip
    if np.allclose(linear, np.eye(2)):
        return out
    motion = (out[..., :2].astype(np.float32) - 128.0) @ linear.T.astype(np.float32)  # (size, size, 2)
    out[..., :2] = np.clip(np.rint(128.0 + motion), 0, 255).astype(np.uint8)
    return out


def to_cells(points: np.ndarray, stride: int) -> np.ndarray:
    """Crop pixels -> output-grid cell coordinates."""
    return (points - (stride - 1) / 2.0) / stride


def from_cells(cells: np.ndarray, stride: int) -> np.ndarray:
    """Output-grid cell coordinates -> crop pixels."""
    return cells * stride + (stride - 1) / 2.0


def _grid(shape: tuple[int, int]) -> np.ndarray:
    ys, xs = np.mgrid[0:shape[0], 0:shape[1]].astype(np.float32)
    return np.stack([xs, ys], axis=-1)  # (hy, hx, 2) as (x, y)


def confidence_maps(points: np.ndarray, visible: np.ndarray, shape: tuple[int, int], sigma: float) -> np.ndarray:
    """Ground-truth confidence maps, one per reflector plus background.  (R, 2) cells -> (R + 1, hy, hx)

    S*_r(p) = exp(-||p - x_r||^2 / sigma^2)   # Eq. (4), DeepMoCap; zero for a reflector not seen
    background = 1 - max_r S*_r
    """
    grid = _grid(shape)
    d2 = ((grid[None] - points[:, None, None, :].astype(np.float32)) ** 2).sum(-1)  # (R, hy, hx)
    maps = np.exp(-d2 / sigma**2) * np.asarray(visible, np.float32)[:, None, None]
    return np.concatenate([maps, 1.0 - maps.max(axis=0, keepdims=True)]).astype(np.float32)


def flow_fields(start: np.ndarray, end: np.ndarray, visible: np.ndarray, shape: tuple[int, int],
                width: float) -> np.ndarray:
    """Ground-truth optical flow fields along each reflector's move from f-1 to f.  (R, 2) cells -> (R, 2, hy, hx)

    v = (x_f - x_{f-1}) / ||x_f - x_{f-1}||; L*_r(p) = v where 0 <= v.(p - x_{f-1}) <= ||x_f - x_{f-1}||
    and |v_perp.(p - x_{f-1})| <= sigma_R, else 0   # Eq. (5)-(6), DeepMoCap; zero for a still reflector
    """
    grid = _grid(shape)
    delta = (end - start).astype(np.float32)  # (R, 2)
    length = np.linalg.norm(delta, axis=-1)  # (R,)
    moving = (length > 1e-6) & np.asarray(visible, bool)
    v = np.where(moving[:, None], delta / np.maximum(length, 1e-6)[:, None], 0.0)  # (R, 2)
    rel = grid[None] - start[:, None, None, :].astype(np.float32)  # (R, hy, hx, 2)
    along = (rel * v[:, None, None, :]).sum(-1)
    across = np.abs(rel[..., 0] * v[:, None, None, 1] - rel[..., 1] * v[:, None, None, 0])
    on = (along >= 0) & (along <= length[:, None, None]) & (across <= width) & moving[:, None, None]
    return (on[:, None] * v[:, :, None, None]).astype(np.float32)

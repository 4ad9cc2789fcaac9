"""Reflector masks and colorized depth (DeepMoCap §3.2, Figures 3-4).

Retro-reflectors saturate the IR image, so a hard threshold on IR finds them; a small opening and
closing removes sensor specks and fills pinholes, and connected components (with their pixel
counts, kept for the 2D filtering of §5.1.3) separate the blobs. The FCN's depth input ``I_CD`` is
the depth image mapped through the JET colormap over a fixed range, with the reflector mask
subtracted (black) — invalid depth is black as well.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import cv2
import numpy as np
import xarray as xr


def reflector_mask(ir: np.ndarray, *, threshold: int, open_px: int, close_px: int, min_area: int,
                   max_components: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Mask, component labels and component areas of one IR image.

    ir (y, x) uint16 -> mask (y, x) bool, labels (y, x) uint16 (0 = none, 1..K), areas (max_components,) int32
    Components are numbered by decreasing area; beyond ``max_components`` the smallest are dropped.
    """
    bright = ir >= threshold
    areas = np.zeros(max_components, np.int32)
    labels = np.zeros(ir.shape, np.uint16)
    rows, cols = np.flatnonzero(bright.any(axis=1)), np.flatnonzero(bright.any(axis=0))
    if rows.size == 0:
        return labels > 0, labels, areas
    # Only the box around the bright pixels: the morphology reaches at most open + close pixels beyond them, so
    # with this margin every pixel of the box sees what it would in the whole image (the box's own border, where
    # OpenCV assumes other values than the image's zeros, stays out of every result).
    grow = 2 * (open_px + close_px) + 2
    box = (slice(max(0, rows[0] - grow), rows[-1] + grow + 1), slice(max(0, cols[0] - grow), cols[-1] + grow + 1))
    mask = bright[box].astype(np.uint8)
    if open_px > 0:
        mask = cv2.morphologyEx(mask, cv2.MORPH_OPEN, _disk(open_px))
    if close_px > 0:
        mask = cv2.morphologyEx(mask, cv2.MORPH_CLOSE, _disk(close_px))
    count, inside, stats, _ = cv2.connectedComponentsWithStats(mask, connectivity=8)  # raster order, as whole
    area = stats[1:, cv2.CC_STAT_AREA]  # (count - 1,)
    keep = np.flatnonzero(area >= min_area)
    keep = keep[np.argsort(-area[keep], kind="stable")][:max_components]
    relabel = np.zeros(count, np.uint16)
    relabel[keep + 1] = np.arange(1, len(keep) + 1)
    labels[box] = relabel[inside]
    areas[:len(keep)] = area[keep]
    return labels > 0, labels, areas


def colorize_depth(depth: np.ndarray, mask: np.ndarray, *, near_mm: float, far_mm: float) -> np.ndarray:
    """``I_CD``: JET over [near, far] mm (near red, far blue), reflectors and invalid depth black.

    depth (y, x) uint16 mm, mask (y, x) bool -> (y, x, 3) uint8 RGB
    """
    levels, colors = _jet_tables(float(near_mm), float(far_mm))
    rgb = cv2.applyColorMap(np.take(levels, depth), colors)  # each depth's JET level, then that level's colour
    seen = ((depth > 0) & ~mask).view(np.uint8)
    return cv2.bitwise_and(rgb, rgb, dst=np.zeros_like(rgb), mask=seen)  # black elsewhere


@functools.lru_cache(maxsize=8)
def _jet_tables(near_mm: float, far_mm: float) -> tuple[np.ndarray, np.ndarray]:
    """The JET level (0 far .. 255 near) of every uint16 depth in mm, and JET's colours in RGB order, for
    ``cv2.applyColorMap``.  -> (65536,) uint8, (256, 1, 3) uint8"""
    depth = np.arange(65536, dtype=np.float32)
    scaled = np.clip((depth - near_mm) / (far_mm - near_mm), 0.0, 1.0)
    levels = np.rint(255 * (1.0 - scaled)).astype(np.uint8)
    bgr = cv2.applyColorMap(np.arange(256, dtype=np.uint8)[:, None], cv2.COLORMAP_JET)  # (256, 1, 3)
    return levels, np.ascontiguousarray(bgr[..., ::-1])


def _disk(radius: int) -> np.ndarray:
    return cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * radius + 1, 2 * radius + 1))


@dataclass(frozen=True)
class MaskConfig:
    """Stage `masks`: IR threshold (counts), morphology radii (px), smallest blob (px), blobs kept,
    and the colorized-depth range (mm)."""

    ir_threshold: int = 30000
    open_px: int = 0
    close_px: int = 1
    min_area: int = 2
    max_components: int = 64
    near_mm: float = 1000.0
    far_mm: float = 4000.0

    def __post_init__(self):
        if not 0 < self.near_mm < self.far_mm:
            raise ValueError(f"colorized depth range [{self.near_mm}, {self.far_mm}] mm must satisfy 0 < near < far")


def masks(frames: xr.Dataset, config: MaskConfig) -> xr.Dataset:
    """Stage `masks`: per view and frame, the reflector mask, its components and the colorized depth."""
    near_mm, far_mm = config.near_mm, config.far_mm
    ir = frames["ir"].values  # (view, frame, y, x)
    depth = frames["depth"].values
    n_views, n_frames = ir.shape[:2]
    mask = np.zeros(ir.shape, bool)
    labels = np.zeros(ir.shape, np.uint16)
    areas = np.zeros((n_views, n_frames, config.max_components), np.int32)
    colored = np.zeros(ir.shape + (3,), np.uint8)
    for v in range(n_views):
        for f in range(n_frames):
            mask[v, f], labels[v, f], areas[v, f] = reflector_mask(
                ir[v, f], threshold=config.ir_threshold, open_px=config.open_px, close_px=config.close_px,
                min_area=config.min_area, max_components=config.max_components)
            colored[v, f] = colorize_depth(depth[v, f], mask[v, f], near_mm=near_mm, far_mm=far_mm)
    dims = ("view", "frame", "y", "x")
    return xr.Dataset(
        {"mask": (dims, mask), "blob_id": (dims, labels),
         "blob_area": (("view", "frame", "blob"), areas),
         "colorized_depth": (dims + ("rgb",), colored)},
        coords={"view": frames["view"].values, "frame": frames["frame"].values,
                "rgb": np.array(["r", "g", "b"], dtype=object)},
        attrs={"ir_threshold": config.ir_threshold, "near_mm": near_mm, "far_mm": far_mm},
    )

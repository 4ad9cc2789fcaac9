"""3D optical flow between consecutive frames of a view (DeepMoCap §3.2), the fast variant and the shared parts.

For frame f the stage reports, at every pixel of frame f, the camera-frame 3D motion (metres) of
the surface seen there from frame f-1 to f, and the colorized flow image ``I_F`` in which each
axis of the motion is normalized into one channel. Two estimators fill it:

- ``dis``: OpenCV's DIS optical flow on IR (with its variational refinement), from frame f to
  f-1, lifted to 3D by back-projecting both depth maps through the calibration;
- ``primal_dual``: the variational RGB-D scene flow of Jaimez et al. (see pdflow.py).

Invalid depth never yields motion: a pixel's motion is reported only where its own depth is
valid, its correspondence in frame f-1 lies inside the image on valid depth, and the implied
depth change is at most ``max_depth_jump`` metres per frame (larger jumps are occlusions or
mismatches at silhouettes). Everywhere else — reflector holes, out-of-range and dropout pixels,
the first frame of a sequence — the motion is 0 and ``valid`` is false.

``dis`` may estimate only around the subject (``roi_ir`` > 0): in the box of both frames' reflector
pixels (IR at or above ``roi_ir``) grown by ``roi_margin_px``. The FCN's crop is centred on the same
reflectors (tasks/deepmocap/training.py) but reaches further, and sees no motion there: outside the box the
motion is 0 and ``valid`` false, as for invalid depth. A frame pair without reflector pixels gets the
whole image. On by default (``roi_ir`` 30000, the masks' threshold): the stage runs 2.4x faster and the
held-out figures move no further than rounding alone moves them (docs/results.md, "On a CPU without AMX").
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field

import cv2
import numpy as np
import xarray as xr

from mocapflow.tasks.shared.cameras import backproject, camera_of

DIS_PRESETS = {"ultrafast": cv2.DISOPTICAL_FLOW_PRESET_ULTRAFAST, "fast": cv2.DISOPTICAL_FLOW_PRESET_FAST,
               "medium": cv2.DISOPTICAL_FLOW_PRESET_MEDIUM}


def ir_to_8bit(ir: np.ndarray, ir_max: float) -> np.ndarray:
    """IR counts to 8 bits with a square-root curve (more levels for the dim body than for reflectors)."""
    if ir.dtype == np.uint16:  # the sensors' counts: a table of the same formula, three times faster
        return np.take(_ir_table(float(ir_max)), ir)
    return np.rint(255.0 * np.sqrt(np.clip(ir.astype(np.float32) / ir_max, 0.0, 1.0))).astype(np.uint8)


@functools.lru_cache(maxsize=8)
def _ir_table(ir_max: float) -> np.ndarray:
    """``ir_to_8bit`` of every 16-bit count (the formula, on the counts as floats).  -> (65536,) uint8"""
    table = ir_to_8bit(np.arange(65536, dtype=np.float32), ir_max)
    table.flags.writeable = False
    return table


def dis_flow(ir_ref: np.ndarray, ir_other: np.ndarray, *, preset: str, refine_iterations: int) -> np.ndarray:
    """2D flow (pixels) from ``ir_ref`` to ``ir_other`` (both 8-bit).  (y, x) -> (y, x, 2)"""
    dis = cv2.DISOpticalFlow_create(DIS_PRESETS[preset])
    dis.setVariationalRefinementIterations(refine_iterations)
    return dis.calc(ir_ref, ir_other, None)


def subject_box(ir_a: np.ndarray, ir_b: np.ndarray, *, threshold: float, margin_px: int,
                min_side_px: int = 64) -> tuple[slice, slice]:
    """Rows and columns around the pixels of either frame at or above ``threshold``, grown by ``margin_px``
    and to at least ``min_side_px`` a side (DIS needs a few patches); the whole image when none is.
    (y, x) x2 -> (rows, cols)"""
    h, w = ir_a.shape
    bright = (ir_a >= threshold) | (ir_b >= threshold)
    rows, cols = np.flatnonzero(bright.any(axis=1)), np.flatnonzero(bright.any(axis=0))
    if rows.size == 0:
        return slice(0, h), slice(0, w)
    return _span(rows[0], rows[-1], margin_px, min_side_px, h), _span(cols[0], cols[-1], margin_px, min_side_px, w)


def _span(first: int, last: int, margin: int, min_side: int, size: int) -> slice:
    """[first - margin, last + margin] widened about its centre to ``min_side``, kept inside [0, size)."""
    grow = max(0, min_side - (last - first + 1 + 2 * margin)) / 2
    lo, hi = int(first - margin - np.ceil(grow)), int(last + margin + np.ceil(grow)) + 1
    lo, hi = max(0, lo), min(size, hi)
    return slice(lo, hi)


def lift_points(flow2d: np.ndarray, z_ref: np.ndarray, z_other: np.ndarray, rays: np.ndarray,
                max_depth_jump: float, z_corr: np.ndarray | None = None,
                consistency: float = 0.04) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """3D motion from the other frame to the reference one, at the reference pixels with depth (only
    they can move: every other pixel has no motion and is not valid).

    flow2d (y, x, 2) pixels ref -> other; z_ref, z_other (y, x) metres, 0 invalid; rays (y, x, 3).
    z_corr: the other frame's depth at the correspondence if the estimator solved for it (else it
    is read from ``z_other`` at the nearest pixel); it must then agree with the measured depth
    there within ``consistency`` metres. Returns the pixels' flat indices at (n,), their motion
    (n, 3) float32 (meaningful where valid only) and valid (n,).
    """
    h, w = z_ref.shape
    at = np.flatnonzero(z_ref > 0)
    rows, cols = np.divmod(at, w)
    step = gather_rows(flow2d, at)  # (n, 2)
    xo = cols.astype(np.float32) + step[:, 0]  # (n,) where each of those pixels went
    yo = rows.astype(np.float32) + step[:, 1]
    inside = (xo >= 0) & (xo <= w - 1) & (yo >= 0) & (yo <= h - 1)
    z_near = _sample(z_other.astype(np.float32, copy=False), xo, yo, cv2.INTER_NEAREST, cv2.BORDER_CONSTANT)
    z_r = z_ref.ravel()[at].astype(np.float32, copy=False)
    z_o = z_near if z_corr is None else z_corr.ravel()[at].astype(np.float32, copy=False)
    ok = inside & (z_near > 0) & (z_o > 0) & (np.abs(z_o - z_r) <= max_depth_jump)
    if z_corr is not None:
        ok &= np.abs(z_near - z_o) <= consistency
    rays32 = rays.astype(np.float32, copy=False)
    rays_o = _sample(rays32, xo, yo, cv2.INTER_LINEAR, cv2.BORDER_REPLICATE)  # (n, 3)
    moved = backproject(z_r, gather_rows(rays32, at)) - backproject(z_o, rays_o)
    return at, moved, ok


def _as_rows(a: np.ndarray) -> np.ndarray:
    """A C-contiguous (..., k) array seen as (...,) items of k values each: fancy indexing then moves one item
    per row instead of k values (several times faster; the same bytes).  (..., k) -> (...,) void"""
    assert a.flags.c_contiguous, "row view needs a C-contiguous array"
    return a.view(np.dtype((np.void, a.dtype.itemsize * a.shape[-1]))).reshape(a.shape[:-1])


def gather_rows(image: np.ndarray, at: np.ndarray) -> np.ndarray:
    """The pixels ``at`` (flat indices) of a multi-channel image.  (y, x, c), (n,) -> (n, c)"""
    image = np.ascontiguousarray(image)  # a crop's view is copied
    return _as_rows(image).ravel()[at].view(image.dtype).reshape(-1, image.shape[-1])


def scatter_rows(image: np.ndarray, at: np.ndarray, values: np.ndarray) -> None:
    """image's pixels ``at`` (flat indices) := values, in place.  (..., c) C-contiguous, (n,), (n, c)"""
    _as_rows(image).reshape(-1)[at] = _as_rows(np.ascontiguousarray(values, dtype=image.dtype))


def _sample(image: np.ndarray, x: np.ndarray, y: np.ndarray, interpolation: int, border: int) -> np.ndarray:
    """``image`` at points (x, y) as cv2.remap samples it (remap maps are images: the points go in rows of
    1024).  (h, w[, c]), (n,) x2 -> (n[, c])"""
    n, side = len(x), 1024
    rows = max(1, -(-n // side))
    maps = [np.full(rows * side, -1.0, np.float32) for _ in range(2)]
    maps[0][:n], maps[1][:n] = x, y
    out = cv2.remap(image, maps[0].reshape(rows, side), maps[1].reshape(rows, side), interpolation, borderMode=border)
    return out.reshape((rows * side,) + image.shape[2:])[:n]


def flow_colors(motion: np.ndarray, scale_m: float) -> np.ndarray:
    """``I_F`` of motions (m): 128 + 127·motion/scale_m, rounded into [0, 255].  (..., 3) -> (..., 3) uint8"""
    return np.rint(np.clip(128.0 + 127.0 * motion / scale_m, 0, 255)).astype(np.uint8)


def rays_for(frames: xr.Dataset, view) -> np.ndarray:
    """Pixel rays of one view of a raw sequence, from its calibration variables."""
    return camera_of(frames, view).pixel_rays()  # memoized per calibration


def flow_sequence(frames: xr.Dataset, estimate, *, color_scale_m: float, max_depth_jump: float,
                  prepare=None) -> xr.Dataset:
    """Apply a pairwise estimator ``estimate(ir_ref, ir_prev, z_ref_m, z_prev_m, rays) -> (at, motion, valid)``
    (``lift_points``' form: flat pixel indices and their motion and validity; every other pixel has no
    motion) to every frame with its predecessor in ``frames`` (the first frame of a sequence gets no motion).
    ``prepare``: what the estimator receives of each frame's IR instead of the IR itself, made once per frame
    (a frame is the reference of one pair and the predecessor of the next)."""
    depth = frames["depth"].values  # (view, frame, y, x) mm
    ir = frames["ir"].values
    frame_ids = frames["frame"].values
    assert np.all(np.diff(frame_ids) == 1), "flow needs consecutive frames"
    motion = np.zeros(depth.shape + (3,), np.float16)
    valid = np.zeros(depth.shape, bool)
    colored = np.full(depth.shape + (3,), 128, np.uint8)
    for v, view in enumerate(frames["view"].values):
        rays = rays_for(frames, view).astype(np.float32)  # once per view, not per pair
        z = depth[v].astype(np.float32) / 1000.0  # (frame, y, x) metres
        images = [ir[v, i] if prepare is None else prepare(ir[v, i]) for i in range(len(frame_ids))]
        for i in range(1, len(frame_ids)):
            at, m, ok = estimate(images[i], images[i - 1], z[i], z[i - 1], rays)
            m[~ok] = 0.0  # the outputs start as no motion, 128 and not valid, as these pixels stay
            scatter_rows(motion[v, i], at, m)
            valid[v, i].ravel()[at] = ok
            scatter_rows(colored[v, i], at, flow_colors(m, color_scale_m))
    dims = ("view", "frame", "y", "x")
    return xr.Dataset(
        {"flow": (dims + ("xyz",), motion), "valid": (dims, valid), "colorized_flow": (dims + ("rgb",), colored)},
        coords={"view": frames["view"].values, "frame": frame_ids,
                "xyz": np.array(["x", "y", "z"], dtype=object), "rgb": np.array(["r", "g", "b"], dtype=object)},
        attrs={"units": "m", "frame_convention": "motion from frame f-1 to f at the pixels of frame f, camera axes",
               "color_scale_m": color_scale_m})


@dataclass(frozen=True)
class DisConfig:
    """Stage `flow`, implementation `dis`: DIS preset and variational refinement iterations, the IR level
    mapped to white, the largest plausible depth change per frame (m), and the flow-image scale (m)."""

    preset: str = "medium"
    refine_iterations: int = 2
    ir_max: float = 12000.0
    max_depth_jump: float = 0.15
    color_scale_m: float = 0.05
    # > 0: estimate only around the pixels this bright (the reflectors, the masks' threshold) in either frame;
    # 0: the whole image. Around the subject the stage runs 2.4x faster with the same held-out figures to within
    # the spread that rounding alone gives them (docs/results.md, "On a CPU without AMX").
    roi_ir: float = 30000.0
    roi_margin_px: int = 32  # the box around them grows by this much on each side

    def __post_init__(self):
        if self.preset not in DIS_PRESETS:
            raise ValueError(f"unknown DIS preset {self.preset!r}; use one of {sorted(DIS_PRESETS)}")
        if self.roi_ir < 0 or self.roi_margin_px < 0:
            raise ValueError(f"roi_ir and roi_margin_px must be >= 0 (0 roi_ir: the whole image), got "
                             f"{self.roi_ir} and {self.roi_margin_px}")


@dataclass(frozen=True)
class PrimalDualConfig:
    """Stage `flow`, implementation `primal_dual` (pdflow.py): the energy's weights (see the module docstring), the
    solver's iterations per warp, warps per level and finest pyramid level (0 = full resolution), the
    IR level mapped to 1, the plausibility checks of the lifting (m), the flow-image scale (m), and
    the torch device ("auto": a GPU when present)."""

    lambda_uv: float = 1.0
    lambda_w: float = 0.02
    mu: float = 20.0
    z_edge: float = 0.03
    normalize_eps: float = 0.01
    iterations: int = 20
    warps: int = 4
    finest_level: int = 1
    ir_max: float = 12000.0
    max_depth_jump: float = 0.15
    consistency: float = 0.04
    color_scale_m: float = 0.05
    device: str = field(default="auto", metadata={"runtime": True})  # where it runs, not what it computes


def dis(frames: xr.Dataset, config: DisConfig) -> xr.Dataset:
    """Stage `flow`, implementation `dis`: DIS optical flow on IR lifted to 3D with both depth maps
    (around the subject only, where ``roi_ir`` > 0)."""
    roi_ir = config.roi_ir

    def eight_bit(ir):
        return ir, ir_to_8bit(ir, config.ir_max)

    def estimate(ref, prev, z_ref, z_prev, rays):  # ref, prev: (IR, its 8 bits) of the two frames
        box = (slice(None), slice(None))
        if roi_ir > 0:
            box = subject_box(ref[0], prev[0], threshold=roi_ir, margin_px=config.roi_margin_px)
        flow2d = dis_flow(np.ascontiguousarray(ref[1][box]), np.ascontiguousarray(prev[1][box]), preset=config.preset,
                          refine_iterations=config.refine_iterations)  # (h', w', 2) inside the box
        at, motion, valid = lift_points(flow2d, z_ref[box], z_prev[box], rays[box], config.max_depth_jump)
        if roi_ir > 0:  # the box's flat indices -> the image's
            rows, cols = np.divmod(at, flow2d.shape[1])
            at = (rows + box[0].start) * z_ref.shape[1] + cols + box[1].start
        return at, motion, valid

    return flow_sequence(frames, estimate, color_scale_m=config.color_scale_m, max_depth_jump=config.max_depth_jump,
                         prepare=eight_bit)

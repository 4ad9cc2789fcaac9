"""The Kinect v2's time-of-flight artefacts, beyond the range noise of render.kinect_depth.

A Kinect v2 measures depth by the phase of amplitude-modulated infrared light, at three modulation frequencies with
three phase steps each, nine raw images per depth frame (Sell & O'Connor 2014, IEEE Micro 34(2)). Four consequences
the studio's plain sensor leaves out, switched on together by a sequence's ``tof_artefacts: true``:

- **multipath** (``multipath``): light that reaches a surface by way of another (the floor, the wall) arrives late, so
  depth reads too far, by up to a few centimetres in concave corners (Fuchs 2010, "Multipath interference compensation
  in time-of-flight camera images", ICPR; Freedman et al. 2014, "SRA: fast removal of general multipath for ToF
  sensors", ECCV; Fürsattel et al. 2016, IEEE TCI 2(1), measured on the Kinect v2). Here: surfaces within
  MULTIPATH_REACH_M of the floor (the body's feet and shins, the wall's foot) and floor within that reach of the wall;
- **flying pixels** (``flying_pixels``): a pixel whose footprint straddles a silhouette mixes the phases of the near
  and the far surface and reads a depth between them (Sarbolandi et al. 2015, "Kinect range sensing: structured-light
  versus time-of-flight Kinect", CVIU 139). Here: every pixel beside a depth jump of more than EDGE_JUMP_M;
- **motion** (``motion_smear``): the nine raw images are taken one after the other, so a surface that moves while they
  are taken is measured at several places (Lindner & Kolb 2009, "Compensation of motion artifacts for time-of-flight
  cameras", Dyn3D; Hansard et al. 2013, "Time-of-flight cameras", Springer). Here: depth is the mean of three samples
  along the pixel's image motion over RAW_SPAN_S, and dropped where they disagree by more than the unwrapping allows;
- **interference** (``interference_depth``, ``interference_ir``): the other sensors' modulated light falls on the
  same surfaces; unsynchronised, it adds noise and, where it beats with the sensor's own, wrong or no depth (the
  mechanism: Li 2014, "Time-of-flight camera - an introduction", TI SLOA190B; Sarbolandi et al. 2015 measured the
  Kinect v2's multi-device interference as small but present). Here: per other sensor seeing a surface, more depth
  noise, a few dropouts and more IR noise.

The numbers marked "assumption" are chosen to be of the size the sources report, not fitted to a sensor. Pure
functions of arrays and a random generator; camera z in metres throughout.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from scipy import ndimage

MULTIPATH_BIAS_M = 0.025  # bias at contact with the floor: the few-cm corner errors of Fuchs, Freedman, Fürsattel
MULTIPATH_DECAY_M = 0.10  # it halves about every 7 cm away from the corner (an assumption)
MULTIPATH_REACH_M = 0.30  # and stops beyond 30 cm (an assumption; keeps it local)
MULTIPATH_NOISE = 0.3  # its noise: a share of the bias (the indirect path's strength varies; an assumption)
EDGE_JUMP_M = 0.05  # a depth jump that makes flying pixels (a few cm: the Kinect v2's mixed pixels at edges)
RAW_SPAN_S = 0.015  # the nine raw images of a frame span about half its 33 ms (an assumption; Sell & O'Connor 2014)
SMEAR_MIN_PX = 1.0  # motion below a pixel over the raw span leaves depth alone
UNWRAP_JUMP_M = 0.05  # samples that disagree by more than this break the phase unwrapping: dropped half the time
INTERFERENCE_NOISE = 1.0  # per other sensor: extra depth noise as a share of the sensor's own (an assumption)
INTERFERENCE_DROP = 0.02  # per other sensor: share of its pixels with no depth (an assumption)
INTERFERENCE_IR = 0.03  # per other sensor: IR noise, a share of the signal (an assumption)


class ToFError(ValueError):
    """Arrays the time-of-flight artefacts cannot be applied to."""


@dataclass(frozen=True)
class Motion:
    """Each pixel's image motion over the raw images' span, pixels: (y, x, 2) (dx, dy), 0 where still."""

    shift: np.ndarray


def floor_proximity(world: np.ndarray, floor: np.ndarray, room_radius: float) -> np.ndarray:
    """How far each visible point is from a floor corner, metres: its height above the floor, or (a floor point) its
    distance to the room's wall.  world (y, x, 3), floor (y, x) bool -> (y, x)"""
    height = world[..., 2]
    to_wall = room_radius - np.hypot(world[..., 0], world[..., 1])
    return np.where(floor, np.maximum(to_wall, 0.0), np.maximum(height, 0.0))


def multipath(z: np.ndarray, ray_z: np.ndarray, proximity: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Depth read too far near a floor corner: the ray's length grows by MULTIPATH_BIAS_M exp(-proximity / decay)
    (with noise), nothing beyond MULTIPATH_REACH_M.  z, ray_z (camera z of the unit ray), proximity (y, x) -> (y, x)"""
    bias = MULTIPATH_BIAS_M * np.exp(-proximity / MULTIPATH_DECAY_M)
    bias *= 1.0 + MULTIPATH_NOISE * rng.standard_normal(z.shape)
    bias = np.where((proximity <= MULTIPATH_REACH_M) & (z > 0), np.maximum(bias, 0.0), 0.0)
    return z + bias * ray_z


def silhouette(z: np.ndarray) -> np.ndarray:
    """Pixels beside a depth jump of more than EDGE_JUMP_M (4-neighbours), on both sides.  (y, x) -> (y, x) bool"""
    out = np.zeros(z.shape, bool)
    for axis in (0, 1):
        jump = np.abs(np.diff(z, axis=axis)) > EDGE_JUMP_M
        lo = [slice(None)] * 2
        hi = [slice(None)] * 2
        lo[axis], hi[axis] = slice(0, -1), slice(1, None)
        out[tuple(lo)] |= jump
        out[tuple(hi)] |= jump
    return out


def flying_pixels(z: np.ndarray, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Each silhouette pixel reads a mix of the nearest and farthest surface round it, weighted by a random share of
    its footprint: z_near + w (z_far - z_near), w uniform.  (y, x) -> (y, x) depth, (y, x) bool the flying pixels"""
    edge = silhouette(z)
    near = cv2.erode(z.astype(np.float32), np.ones((3, 3), np.uint8)).astype(z.dtype)
    far = cv2.dilate(z.astype(np.float32), np.ones((3, 3), np.uint8)).astype(z.dtype)
    w = rng.random(z.shape)
    return np.where(edge, near + w * (far - near), z), edge


def image_motion(points: np.ndarray, velocity: np.ndarray, fx: float, fy: float, moving: np.ndarray,
                 fps: float) -> Motion:
    """Image motion over RAW_SPAN_S of surface ``points`` (y, x, 3, camera frame) moving at ``velocity`` (y, x, 3,
    metres per frame at ``fps``), where ``moving`` (y, x) bool: the pinhole Jacobian of the motion."""
    span = RAW_SPAN_S * fps  # frames
    z = np.maximum(points[..., 2], 1e-6)
    dx = fx * (velocity[..., 0] / z - points[..., 0] * velocity[..., 2] / z**2) * span
    dy = fy * (velocity[..., 1] / z - points[..., 1] * velocity[..., 2] / z**2) * span
    return Motion(np.where(moving[..., None], np.stack([dx, dy], axis=-1), 0.0))


def motion_smear(z: np.ndarray, motion: Motion, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Depth over a moving surface's path: where a pixel (or a neighbour within its motion) moves SMEAR_MIN_PX or more
    over the raw span, the mean of z at the pixel and half the motion before and after it; where those samples
    disagree by more than UNWRAP_JUMP_M, dropped half the time.  z (y, x) -> (y, x) depth, (y, x) bool dropped"""
    shift = motion.shift
    speed = np.hypot(shift[..., 0], shift[..., 1])
    moving = speed >= SMEAR_MIN_PX
    if not moving.any():
        return z, np.zeros(z.shape, bool)
    # a still pixel the moving surface passes over during the span takes its neighbour's motion
    dist, (iy, ix) = ndimage.distance_transform_edt(~moving, return_indices=True)
    reach = speed[iy, ix] / 2 + 1.0
    near = dist <= reach
    shift = np.where(near[..., None], shift[iy, ix], 0.0)
    h, w = z.shape
    ys, xs = np.nonzero(near)
    samples = []
    for s in (-0.5, 0.0, 0.5):
        sx = np.clip(np.rint(xs - s * shift[ys, xs, 0]), 0, w - 1).astype(np.int64)
        sy = np.clip(np.rint(ys - s * shift[ys, xs, 1]), 0, h - 1).astype(np.int64)
        samples.append(z[sy, sx])
    samples = np.stack(samples)
    out = z.copy()
    out[ys, xs] = samples.mean(axis=0)
    dropped = np.zeros(z.shape, bool)
    dropped[ys, xs] = (np.ptp(samples, axis=0) > UNWRAP_JUMP_M) & (rng.random(len(ys)) < 0.5)
    return out, dropped


def sensors_seeing(world: np.ndarray, normals: np.ndarray, cams, valid: np.ndarray) -> np.ndarray:
    """How many of ``cams`` (tasks.shared.cameras.Camera) light each surface point: it lies in the camera's pinhole
    frustum (the lens's distortion moves the frustum's edge by a few pixels: left out) and faces it (occlusion by the
    body is ignored).  world, normals (y, x, 3), valid (y, x) -> (y, x) int"""
    count = np.zeros(world.shape[:2], np.int16)
    idx = np.flatnonzero(valid)
    if not len(idx):
        return count
    p, n = world.reshape(-1, 3)[idx], normals.reshape(-1, 3)[idx]
    for cam in cams:
        w2c = cam.world_to_cam
        pc = p @ w2c[:3, :3].T + w2c[:3, 3]
        z = np.maximum(pc[:, 2], 1e-9)
        x, y = cam.fx * pc[:, 0] / z + cam.cx, cam.fy * pc[:, 1] / z + cam.cy
        inside = (pc[:, 2] > 0) & (x >= 0) & (x < cam.width) & (y >= 0) & (y < cam.height)
        facing = np.einsum("ni,ni->n", n, cam.cam_to_world[:3, 3] - p) > 0
        count.ravel()[idx] += (inside & facing).astype(np.int16)
    return count


def interference_depth(z: np.ndarray, others: np.ndarray, noise: float,
                       rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """More depth noise and dropouts where ``others`` (y, x) other sensors light the surface: noise sigma
    INTERFERENCE_NOISE x the sensor's own (render.kinect_depth's) per other sensor, INTERFERENCE_DROP of the pixels
    lost per other sensor.  -> (y, x) depth, (y, x) bool dropped"""
    if z.shape != others.shape:
        raise ToFError(f"depth {z.shape} and the sensor count {others.shape} differ in shape; give one count a pixel")
    sigma = noise * (0.0006 + 0.00035 * z**2) * INTERFERENCE_NOISE * others
    dropped = rng.random(z.shape) < INTERFERENCE_DROP * others
    return z + sigma * rng.standard_normal(z.shape), dropped


def interference_ir(ir: np.ndarray, others: np.ndarray, saturated: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """IR with the other sensors' light as noise: INTERFERENCE_IR of the signal per other sensor; ``saturated``
    pixels (y, x) bool stay saturated.  uint16 -> uint16"""
    noisy = ir * (1.0 + INTERFERENCE_IR * others * rng.standard_normal(ir.shape))
    return np.where(saturated, ir, np.clip(np.rint(noisy), 0, 65535)).astype(np.uint16)

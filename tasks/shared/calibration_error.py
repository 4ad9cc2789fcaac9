"""Cameras as a real calibration leaves them: each one's pose and intrinsics off by a little, sized by the
reprojection error it causes.

A calibration (wand or board) ends with about 0.2-0.3 px of reprojection RMS: the cameras it returns put a point
of the volume a few tenths of a pixel from where the true cameras see it. ``perturbed`` draws such an error per
camera: a random direction among the parameters a calibration estimates (rotation, position, focal length,
principal point), scaled so that the points of the capture volume reproject ``rms_px`` (RMS) away from their true
pixels. Studio figures made with the true cameras have no calibration error at all.
"""

from __future__ import annotations

import dataclasses
from typing import Sequence

import numpy as np
from scipy.spatial.transform import Rotation

from mocapflow.tasks.shared.cameras import Camera

# The size of one unit of each parameter's draw before scaling: what a calibration gets wrong together.
ROTATION_RAD, POSITION_M, FOCAL_REL, CENTRE_PX = 1e-3, 1e-3, 1e-3, 1.0


class CalibrationErrorError(ValueError):
    """A calibration error that cannot be drawn."""


def volume_points(centre: Sequence[float] = (0.0, 0.0, 1.0), size: Sequence[float] = (2.0, 2.0, 2.0),
                  count: int = 500, seed: int = 0) -> np.ndarray:
    """Points spread through the capture volume, where a calibration's wand goes.  -> (count, 3)"""
    rng = np.random.default_rng([seed, 71])
    return np.asarray(centre, float) + (rng.random((count, 3)) - 0.5) * np.asarray(size, float)


def perturbed(cameras: Sequence[Camera], rms_px: float, rng: np.random.Generator,
              points: np.ndarray | None = None) -> tuple[Camera, ...]:
    """Each camera with a calibration error that moves ``points`` (the volume's, by default) ``rms_px`` RMS in its
    image (over the points it sees in front of it)."""
    if not 0 <= rms_px <= 20:
        raise CalibrationErrorError(f"a calibration error of {rms_px} px RMS; give 0-20 px (a real calibration "
                                    "leaves 0.2-0.3)")
    points = volume_points() if points is None else np.asarray(points, float)
    return tuple(_one(cam, rms_px, rng.standard_normal(9), points) for cam in cameras)


def _one(cam: Camera, rms_px: float, direction: np.ndarray, points: np.ndarray) -> Camera:
    true_xy, z = cam.project(points)
    seen = np.isfinite(true_xy).all(axis=1) & (z > 0)
    if rms_px == 0 or not seen.any():
        return cam
    unit = _moved(cam, direction)
    xy, _ = unit.project(points[seen])
    rms = float(np.sqrt(np.nanmean(np.sum((xy - true_xy[seen]) ** 2, axis=1))))
    # The error is small: reprojection shifts grow linearly with the step, so one rescale lands on the target.
    return _moved(cam, direction * rms_px / max(rms, 1e-12))


def _moved(cam: Camera, d: np.ndarray) -> Camera:
    """``cam`` with its parameters moved by the draw ``d`` (9,): rotation (3), position (3), focal, centre (2)."""
    pose = cam.cam_to_world.copy()
    pose[:3, :3] = Rotation.from_rotvec(d[:3] * ROTATION_RAD).as_matrix() @ pose[:3, :3]
    pose[:3, 3] = pose[:3, 3] + d[3:6] * POSITION_M
    scale = 1 + d[6] * FOCAL_REL
    return dataclasses.replace(cam, fx=cam.fx * scale, fy=cam.fy * scale, cx=cam.cx + d[7] * CENTRE_PX,
                               cy=cam.cy + d[8] * CENTRE_PX, cam_to_world=pose)

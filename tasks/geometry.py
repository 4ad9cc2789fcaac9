"""Camera geometry shared by the stages: intrinsics, undistorted pixel rays, back-projection.

Cameras follow OpenCV: intrinsics fx fy cx cy in pixels, distortion k1 k2 p1 p2 k3. A pixel's ray
is the undistorted direction through its centre, scaled to unit length; a depth value is the
camera-frame z of the surface (Kinect convention), so a point is ``ray * z / ray_z``.
"""

from __future__ import annotations

import functools

import cv2
import numpy as np


def intrinsics(fx: float, fy: float, cx: float, cy: float) -> np.ndarray:
    return np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])


def pixel_rays(K: np.ndarray, dist, width: int, height: int) -> np.ndarray:
    """Unit ray directions (camera frame) through every pixel centre, undistorted.  -> (y, x, 3)

    Memoized per calibration (read-only result): a view's rays are computed once per process.
    """
    return _pixel_rays(tuple(np.asarray(K, float).ravel()), tuple(np.asarray(dist, float).ravel()), width, height)


@functools.lru_cache(maxsize=16)
def _pixel_rays(K: tuple, dist: tuple, width: int, height: int) -> np.ndarray:
    K = np.array(K).reshape(3, 3)
    ys, xs = np.mgrid[0:height, 0:width].astype(np.float64)
    pts = np.stack([xs.ravel(), ys.ravel()], axis=1).reshape(-1, 1, 2)
    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 40, 1e-9)
    norm = cv2.undistortPoints(pts, K, np.asarray(dist, float), criteria=crit).reshape(-1, 2)
    rays = np.concatenate([norm, np.ones((norm.shape[0], 1))], axis=1)
    rays /= np.linalg.norm(rays, axis=1, keepdims=True)
    rays = rays.reshape(height, width, 3)
    rays.flags.writeable = False
    return rays


def backproject(z: np.ndarray, rays: np.ndarray) -> np.ndarray:
    """Camera-frame points of depth ``z`` (metres, any shape S) along ``rays`` (S + (3,))."""
    return rays * (z / rays[..., 2])[..., None]


def project(points: np.ndarray, K: np.ndarray, dist, cam_to_world: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Pixels and camera-frame depth z (metres) of world points; NaN where a point is not finite or lies
    behind the camera.  (n, 3) -> (n, 2), (n,)"""
    world_to_cam = np.linalg.inv(cam_to_world)
    cam = points @ world_to_cam[:3, :3].T + world_to_cam[:3, 3]  # (n, 3)
    ok = np.isfinite(cam).all(axis=1) & (cam[:, 2] > 0)
    uv = np.full((len(points), 2), np.nan)
    if ok.any():
        found, _ = cv2.projectPoints(cam[ok].reshape(-1, 1, 3), np.zeros(3), np.zeros(3), np.asarray(K, float),
                                     np.asarray(dist, float))
        uv[ok] = found.reshape(-1, 2)
    return uv, np.where(ok, cam[:, 2], np.nan)

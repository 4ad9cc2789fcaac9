"""One camera type for every system: OpenCV intrinsics and distortion, a pose, and what is done with them.

Cameras follow OpenCV: intrinsics fx fy cx cy in pixels, distortion k1 k2 p1 p2 k3, camera axes x right,
y down, z forward; the pose is a 4x4 camera-to-world transform in the world frame (Z up, metres). A
pixel's ray is the undistorted direction through its centre, scaled to unit length; a depth value is
the camera-frame z of the surface (Kinect convention), so a point is ``ray * z / ray_z``.

A raw sequence stores each view's calibration as variables (``fx fy cx cy dist cam_to_world width
height``); :func:`camera_of` builds the :class:`Camera` from them once, checked (:func:`calibrated_camera`).

Other systems state a pose otherwise: OpenCV, anipose and Pose2Sim as a world-to-camera rotation and translation
(:func:`pose_from_extrinsics`), Qualisys as a camera position and a rotation of its own camera axes
(:func:`pose_from_qualisys`); :func:`reframed` turns a pose into another world frame (e.g. Y up onto Z up).
Rigs are placed by :func:`look_at` (a camera aimed at a target, its x axis level) on :func:`ring_positions`.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field
from typing import Any

import cv2
import numpy as np

# A Qualisys camera's axes in the OpenCV camera's: x right, y up, z backward (the camera looks along -z).
QUALISYS_CAMERA_AXES = np.diag([1.0, -1.0, -1.0])
CALIBRATION_VARIABLES = ("fx", "fy", "cx", "cy", "dist", "width", "height", "cam_to_world")
_UNDISTORT = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 40, 1e-9)


class CalibrationError(ValueError):
    """A view's calibration cannot be used (not finite, wrong shape)."""


class LayoutError(ValueError):
    """Cameras that cannot be placed (one at its target or looking straight up or down, a sensor without a
    position, an orientation that is not one)."""


@dataclass(frozen=True)
class Camera:
    """A calibrated camera: intrinsics (pixels), distortion (k1 k2 p1 p2 k3), camera-to-world pose, image size."""

    name: str
    fx: float
    fy: float
    cx: float
    cy: float
    dist: tuple[float, ...]
    cam_to_world: np.ndarray = field(repr=False)  # (4, 4)
    width: int
    height: int

    @property
    def K(self) -> np.ndarray:
        return intrinsics(self.fx, self.fy, self.cx, self.cy)

    @property
    def world_to_cam(self) -> np.ndarray:
        return np.linalg.inv(self.cam_to_world)

    def to_camera(self, points: np.ndarray) -> np.ndarray:
        """World points in the camera frame.  (..., 3) -> (..., 3)"""
        w2c = self.world_to_cam
        return points @ w2c[:3, :3].T + w2c[:3, 3]

    def project(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Distorted pixels and camera-frame depth z (metres) of world points; NaN where a point is not finite
        or lies behind the camera.  (n, 3) -> (n, 2), (n,)"""
        return project(points, self.K, self.dist, self.cam_to_world)

    def pixel_rays(self) -> np.ndarray:
        """Unit ray directions (camera frame) through every pixel centre, undistorted.  -> (y, x, 3)"""
        return pixel_rays(self.K, self.dist, self.width, self.height)

    def backproject(self, xy: np.ndarray, depth_m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """World points and unit viewing rays (world) of pixels at camera-frame depths.  (n, 2), (n,) -> (n, 3), (n, 3)"""
        norm = undistort(xy, self.K, self.dist)  # (n, 2)
        cam = np.column_stack([norm * depth_m[:, None], depth_m])  # Kinect depth is the camera-frame z
        rays = np.column_stack([norm, np.ones(len(norm))])
        rays /= np.linalg.norm(rays, axis=1, keepdims=True)
        rot, origin = self.cam_to_world[:3, :3], self.cam_to_world[:3, 3]
        return cam @ rot.T + origin, rays @ rot.T

    def as_dict(self) -> dict[str, Any]:
        """The calibration variables of a raw sequence (see schemas/raw.py)."""
        return {"fx": self.fx, "fy": self.fy, "cx": self.cx, "cy": self.cy, "dist": list(self.dist),
                "cam_to_world": self.cam_to_world, "width": self.width, "height": self.height}


def camera_of(frames, view) -> Camera:
    """The camera of ``view`` from a raw sequence's calibration variables (an xarray Dataset with a view dim)."""
    cal = frames.sel(view=view)
    return calibrated_camera(str(view), **{k: np.asarray(cal[k].values) for k in ("fx", "fy", "cx", "cy", "dist")},
                             cam_to_world=np.asarray(cal["cam_to_world"].values),
                             width=int(cal["width"]) if "width" in cal else 0,
                             height=int(cal["height"]) if "height" in cal else 0)


def calibrated_camera(name: str, *, fx, fy, cx, cy, dist, cam_to_world, width, height) -> Camera:
    """A :class:`Camera` from raw calibration values, checked: finite numbers (``fx``, ``fy`` positive), five
    distortion coefficients, a 4x4 pose, a whole image size (0 where unknown); raise CalibrationError naming the
    view, the value and what it must be."""
    intr = [_number(name, key, value) for key, value in (("fx", fx), ("fy", fy), ("cx", cx), ("cy", cy))]
    if intr[0] <= 0 or intr[1] <= 0:
        raise CalibrationError(f"view {name!r}: focal lengths fx, fy must be positive pixels, got {intr[0]}, {intr[1]}")
    coefs = _array(name, "dist", dist, (5,), "five distortion coefficients [k1, k2, p1, p2, k3]")
    pose = _array(name, "cam_to_world", cam_to_world, (4, 4), "a 4x4 camera-to-world transform (4 rows of 4)")
    size = [_pixels(name, key, value) for key, value in (("width", width), ("height", height))]
    return Camera(name, *intr, dist=tuple(float(d) for d in coefs), cam_to_world=pose, width=size[0], height=size[1])


def _number(view: str, key: str, value) -> float:
    try:
        number = float(np.asarray(value, dtype=np.float64).item())
    except (TypeError, ValueError) as exc:
        raise CalibrationError(f"view {view!r}: {key} must be a number, got {value!r}") from exc
    if not np.isfinite(number):
        raise CalibrationError(f"view {view!r} has a non-finite calibration: {key} = {number}; "
                               "fix the recording's calibration or drop the view")
    return number


def _array(view: str, key: str, value, shape: tuple[int, ...], what: str) -> np.ndarray:
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise CalibrationError(f"view {view!r}: {key} must be {what}, got {value!r}") from exc
    if arr.shape != shape:
        raise CalibrationError(f"view {view!r}: {key} must be {what}, got shape {arr.shape}")
    if not np.isfinite(arr).all():
        raise CalibrationError(f"view {view!r} has a non-finite calibration: {key} = {arr.tolist()}; "
                               "fix the recording's calibration or drop the view")
    return arr


def _pixels(view: str, key: str, value) -> int:
    number = _number(view, key, value)
    if number < 0 or number != int(number):
        raise CalibrationError(f"view {view!r}: {key} must be a whole number of pixels, got {value!r}")
    return int(number)


def intrinsics(fx: float, fy: float, cx: float, cy: float) -> np.ndarray:
    return np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])


def undistort(xy: np.ndarray, K: np.ndarray, dist) -> np.ndarray:
    """Normalized (undistorted) image coordinates of distorted pixels.  (n, 2) -> (n, 2)"""
    pts = np.asarray(xy, np.float64).reshape(-1, 1, 2)
    return cv2.undistortPoints(pts, K, np.asarray(dist, np.float64), criteria=_UNDISTORT).reshape(-1, 2)


def pixel_rays(K: np.ndarray, dist, width: int, height: int) -> np.ndarray:
    """Unit ray directions (camera frame) through every pixel centre, undistorted.  -> (y, x, 3)

    Memoized per calibration (read-only result): a view's rays are computed once per process.
    """
    return _pixel_rays(tuple(np.asarray(K, float).ravel()), tuple(np.asarray(dist, float).ravel()), width, height)


@functools.lru_cache(maxsize=16)
def _pixel_rays(K: tuple, dist: tuple, width: int, height: int) -> np.ndarray:
    ys, xs = np.mgrid[0:height, 0:width].astype(np.float64)
    norm = undistort(np.stack([xs.ravel(), ys.ravel()], axis=1), np.array(K).reshape(3, 3), dist)
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


def look_at(position, target) -> np.ndarray:
    """Camera-to-world transform of a camera at ``position`` aimed at ``target`` (no roll)."""
    position, target = np.asarray(position, float), np.asarray(target, float)
    z = target - position
    if np.linalg.norm(z) < 1e-6:
        raise LayoutError(f"camera at {position.tolist()} coincides with its target")
    z /= np.linalg.norm(z)
    x = np.cross(z, [0.0, 0.0, 1.0])
    if np.linalg.norm(x) < 1e-6:
        raise LayoutError(f"camera at {position.tolist()} looks straight up or down; tilt it, or give its rotation")
    x /= np.linalg.norm(x)
    pose = np.eye(4)
    pose[:3, :3] = np.stack([x, np.cross(z, x), z], axis=1)
    pose[:3, 3] = position
    return pose


def ring_positions(count=3, radius=2.5, height=0.8, start_deg=90.0, spacing_deg=None) -> np.ndarray:
    """Sensor positions on a circle around the centre; the first one faces the subject's front (+Y)."""
    spacing = 360.0 / count if spacing_deg is None else spacing_deg
    angles = np.radians(start_deg + spacing * np.arange(count))
    return np.stack([radius * np.cos(angles), radius * np.sin(angles), np.full(count, height)], axis=1)


def pose_from_extrinsics(rotation: np.ndarray, translation: np.ndarray) -> np.ndarray:
    """The 4x4 camera-to-world pose of OpenCV extrinsics: ``rotation`` world-to-camera, a 3x3 matrix or a Rodrigues
    vector (3,), and ``translation`` world-to-camera (3,), so that ``x_cam = rotation @ x_world + translation``."""
    rotation = np.asarray(rotation, np.float64)
    if rotation.shape != (3, 3):
        rotation = cv2.Rodrigues(rotation.reshape(3, 1))[0]
    world_to_cam = np.eye(4)
    world_to_cam[:3, :3], world_to_cam[:3, 3] = rotation, np.asarray(translation, np.float64).reshape(3)
    return np.linalg.inv(world_to_cam)


def extrinsics_of(cam_to_world: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The OpenCV extrinsics of a pose: world-to-camera Rodrigues vector (3,) and translation (3,); the inverse of
    :func:`pose_from_extrinsics`."""
    world_to_cam = np.linalg.inv(np.asarray(cam_to_world, np.float64))
    return cv2.Rodrigues(world_to_cam[:3, :3])[0].reshape(3), world_to_cam[:3, 3].copy()


def pose_from_qualisys(rotation: np.ndarray, position: np.ndarray) -> np.ndarray:
    """The 4x4 camera-to-world pose of a Qualisys camera (a .qca ``transform``).

    ``rotation`` is the 3x3 matrix of the file's ``r11 .. r33`` laid out as named (``rotation[i - 1, j - 1] = rij``);
    its rows are the Qualisys camera's axes in the world (x right, y up, z backward: the camera looks along -z,
    :data:`QUALISYS_CAMERA_AXES`), i.e. its transpose is the camera-to-world rotation of those axes. ``position`` is
    the camera centre in the world, in the unit wanted (the file's millimetres turned into metres by the caller).
    """
    rotation = np.asarray(rotation, np.float64)
    pose = np.eye(4)
    pose[:3, :3] = rotation.T @ QUALISYS_CAMERA_AXES
    pose[:3, 3] = np.asarray(position, np.float64).reshape(3)
    return pose


def reframed(cam_to_world: np.ndarray, world_rotation: np.ndarray) -> np.ndarray:
    """A camera-to-world pose in a rotated world frame: ``world_rotation`` (3x3) maps the old world's coordinates
    onto the new one's (e.g. ``kinematics.Y_UP_TO_Z_UP``)."""
    turn = np.eye(4)
    turn[:3, :3] = world_rotation
    return turn @ np.asarray(cam_to_world, np.float64)

"""Studio layouts of Kinect-v2-like IR-D sensors: 512x424 depth/IR, about 70.6 x 60 degrees field of view.

The :class:`Camera` type itself is the shared floor's (tasks/shared/cameras.py).

Intrinsics follow OpenCV's pinhole model with radial/tangential distortion (k1 k2 p1 p2 k3).
Extrinsics are 4x4 camera-to-world transforms (OpenCV camera axes: x right, y down, z forward)
in the studio's world frame (Z up, metres). The default layout is DeepMoCap's DMC setup (§4):
three sensors about 120 degrees apart, 2-3 m from the subject, 0.5-1 m high, aimed at the centre.
A layout's sensor is aimed at a target with its x axis level, then turned about its viewing axis by
``roll_deg`` (a real rig's sensors sit 1-3 degrees off level); or its whole orientation is given, as a
3x3 camera-to-world ``rotation`` or a ``quaternion`` [w, x, y, z], where a calibration knows it.
"""

from __future__ import annotations

from typing import Any, Mapping, Sequence

import numpy as np

from scipy.spatial.transform import Rotation

from mocapflow.tasks.shared.cameras import Camera, LayoutError, look_at, ring_positions

WIDTH, HEIGHT = 512, 424
FOV_DEG = (70.6, 60.0)
KINECT_DIST = (0.09, -0.27, 0.0, 0.0, 0.09)
CAPTURE_CENTRE = (0.0, 0.0, 0.9)
ROTATION_TOLERANCE = 1e-4  # a layout's rotation or quaternion may be off by this much (numbers typed at 4-6 places)


def kinect_v2(name: str, cam_to_world: np.ndarray, rng: np.random.Generator | None = None) -> Camera:
    """A sensor with Kinect-v2 intrinsics (per-unit variation of about 1 % when ``rng`` is given)."""
    fx = (WIDTH / 2) / np.tan(np.radians(FOV_DEG[0] / 2))
    fy = (HEIGHT / 2) / np.tan(np.radians(FOV_DEG[1] / 2))
    cx, cy, dist = (WIDTH - 1) / 2, (HEIGHT - 1) / 2, np.array(KINECT_DIST)
    if rng is not None:
        fx, fy = fx * rng.uniform(0.99, 1.01), fy * rng.uniform(0.99, 1.01)
        cx, cy = cx + rng.uniform(-4, 4), cy + rng.uniform(-4, 4)
        dist = dist * rng.uniform(0.8, 1.2, 5)
    return Camera(name, float(fx), float(fy), float(cx), float(cy), tuple(float(d) for d in dist),
                  np.asarray(cam_to_world, float), WIDTH, HEIGHT)


def layout(spec: Mapping[str, Any] | None = None, *, views: int = 3, rng: np.random.Generator | None = None):
    """Cameras from a layout mapping (see below) or the default DMC ring with ``views`` sensors.

    Layout mapping: ``target: [x, y, z]`` (optional) and either
    ``ring: {count, radius, height, start_deg, spacing_deg, roll_deg?}`` (``roll_deg``: one roll for every sensor, or
    one per sensor) or
    ``sensors: [{name, position: [x, y, z], target?, roll_deg?, fx?, fy?, cx?, cy?, dist?}, ...]``, a sensor's
    orientation given instead by ``rotation`` (3x3 camera-to-world) or ``quaternion`` ([w, x, y, z]) where a
    real rig's is known whole (see sensor_pose).
    """
    spec = dict(spec or {"ring": {"count": views}})
    target = np.asarray(spec.get("target", CAPTURE_CENTRE), float)
    if "sensors" in spec:
        cams = [_sensor(i, s, target) for i, s in enumerate(spec["sensors"])]
    else:
        ring = dict(spec.get("ring", {}))
        ring.setdefault("count", views)
        rolls = np.atleast_1d(np.asarray(ring.pop("roll_deg", 0.0), float))
        if rolls.ndim != 1 or len(rolls) not in (1, int(ring["count"])):
            raise LayoutError(f"the ring's roll_deg {rolls.tolist()} must be one number or one per sensor "
                              f"({int(ring['count'])})")
        rolls = np.broadcast_to(rolls, (int(ring["count"]),))
        cams = [kinect_v2(f"kinect{i}", _rolled(look_at(p, target), r), rng)
                for i, (p, r) in enumerate(zip(ring_positions(**ring), rolls))]
    if not cams:
        raise LayoutError("the camera layout has no sensors")
    for cam in cams:
        check_sees(cam, target)
    return cams


def _rolled(pose: np.ndarray, degrees: float) -> np.ndarray:
    """A camera-to-world transform turned by ``degrees`` about its viewing axis (see ``roll``).  (4, 4) -> (4, 4)"""
    out = pose.copy()
    out[:3, :3] = out[:3, :3] @ roll(float(degrees))
    return out


def random_rolls(rng: np.random.Generator, views: int, max_deg: float) -> list[float]:
    """Each sensor's roll about its viewing axis, uniform in ±``max_deg`` (a real rig's sensors sit 1-3° off level)."""
    return [float(r) for r in rng.uniform(-max_deg, max_deg, views)]


def random_ring(rng: np.random.Generator, views: int = 3) -> dict:
    """A random DMC-like layout: 2-3 m away, 0.5-1 m high, roughly evenly spread."""
    return {"ring": {"count": views, "radius": float(rng.uniform(2.0, 3.0)), "height": float(rng.uniform(0.5, 1.0)),
                     "start_deg": float(90 + rng.uniform(-25, 25)), "spacing_deg": float(360 / views + rng.uniform(-10, 10))},
            "target": [float(rng.uniform(-0.1, 0.1)), float(rng.uniform(-0.1, 0.1)), float(rng.uniform(0.8, 1.0))]}


def _sensor(i: int, s: Mapping[str, Any], target: np.ndarray) -> Camera:
    name = str(s.get("name", f"kinect{i}"))
    if "position" not in s:
        raise LayoutError(f"sensor {i} ({name!r}) of the layout has no 'position: [x, y, z]'")
    base = kinect_v2(name, sensor_pose(name, s, target))
    return Camera(name, float(s.get("fx", base.fx)), float(s.get("fy", base.fy)), float(s.get("cx", base.cx)),
                  float(s.get("cy", base.cy)), tuple(float(d) for d in s.get("dist", base.dist)), base.cam_to_world,
                  base.width, base.height)


def sensor_pose(name: str, s: Mapping[str, Any], target: np.ndarray) -> np.ndarray:
    """Camera-to-world transform of a layout sensor: aimed at its ``target`` (the layout's by default) and turned
    by ``roll_deg`` about its viewing axis, or given whole by ``rotation`` or ``quaternion``."""
    given = [k for k in ("rotation", "quaternion") if k in s]
    if given and (len(given) > 1 or {"target", "roll_deg"} & set(s)):
        keys = sorted(set(given) | ({"target", "roll_deg"} & set(s)))
        raise LayoutError(f"sensor {name!r}: its orientation is given more than one way ({', '.join(keys)}); give "
                          "either target (and roll_deg), or rotation, or quaternion")
    position = np.asarray(s["position"], float)
    if given:
        pose = np.eye(4)
        pose[:3, :3] = _rotation(name, s["rotation"]) if "rotation" in s else _quaternion(name, s["quaternion"])
        pose[:3, 3] = position
        return pose
    return _rolled(look_at(position, s.get("target", target)), float(s.get("roll_deg", 0.0)))


def roll(degrees: float) -> np.ndarray:
    """A camera's turn about its viewing axis (+z), applied to its camera-to-world rotation on the right: positive
    turns its x axis (image right) toward its y axis (image down), clockwise seen from behind the camera, so the
    scene turns counter-clockwise in its image."""
    c, s = np.cos(np.radians(degrees)), np.sin(np.radians(degrees))
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _rotation(name: str, value) -> np.ndarray:
    """A 3x3 camera-to-world rotation, checked: orthonormal within ROTATION_TOLERANCE, determinant +1."""
    try:
        rot = np.asarray(value, float)
    except (TypeError, ValueError) as exc:
        raise LayoutError(f"sensor {name!r}: rotation must be 3 rows of 3 numbers, got {value!r}") from exc
    if rot.shape != (3, 3) or not np.isfinite(rot).all():
        raise LayoutError(f"sensor {name!r}: rotation must be 3 rows of 3 finite numbers (camera-to-world: its "
                          f"columns the camera's x right, y down, z forward in world axes), got {value!r}")
    off = np.abs(rot.T @ rot - np.eye(3)).max()
    if off > ROTATION_TOLERANCE:
        raise LayoutError(f"sensor {name!r}: rotation is not orthonormal (R^T R differs from the identity by "
                          f"{off:.2g}); its columns must be unit and perpendicular: the camera's x, y, z in world axes")
    if np.linalg.det(rot) < 0:
        raise LayoutError(f"sensor {name!r}: rotation has determinant {np.linalg.det(rot):.3f}, a reflection; one "
                          "axis is flipped (the camera's axes are x right, y down, z forward, right-handed)")
    u, _, vt = np.linalg.svd(rot)
    return u @ vt  # the nearest rotation: what the tolerance let through made exact


def _quaternion(name: str, value) -> np.ndarray:
    """A camera-to-world rotation from a unit quaternion [w, x, y, z] (scalar first), its norm checked."""
    try:
        q = np.asarray(value, float)
    except (TypeError, ValueError) as exc:
        raise LayoutError(f"sensor {name!r}: quaternion must be 4 numbers [w, x, y, z], got {value!r}") from exc
    if q.shape != (4,) or not np.isfinite(q).all():
        raise LayoutError(f"sensor {name!r}: quaternion must be 4 finite numbers [w, x, y, z], got {value!r}")
    if abs(np.linalg.norm(q) - 1.0) > ROTATION_TOLERANCE:
        raise LayoutError(f"sensor {name!r}: quaternion {q.tolist()} has norm {np.linalg.norm(q):.6g}; a rotation's "
                          "is 1 ([w, x, y, z], scalar first)")
    return Rotation.from_quat(q[[1, 2, 3, 0]]).as_matrix()  # scipy's order is [x, y, z, w]


def check_sees(cam: Camera, point) -> None:
    """Raise LayoutError when ``point`` (world) is behind ``cam`` or outside its image."""
    uv, z = cam.project(np.asarray(point, float)[None])
    if not z[0] > 0.3 or not (0 <= uv[0, 0] < cam.width and 0 <= uv[0, 1] < cam.height):
        raise LayoutError(f"sensor {cam.name!r} does not see the capture centre {np.round(point, 2).tolist()} "
                         f"(it projects to {np.round(uv[0], 1).tolist()} at depth {z[0]:.2f} m); aim it at the subject")


def outside_share(cams: Sequence[Camera], points: np.ndarray) -> np.ndarray:
    """Per camera, the share of the finite ``points`` it cannot see: behind it or outside its image.

    A point is in view when it is in front of the camera (z > 0), its distorted pixel lies in the image, and its
    undistorted direction lies within the image's (the box of its pixel rays' x/z, y/z): OpenCV's distortion
    polynomial is fitted to the field of view and can fold a point far outside it back into the image (Brown-Conrady
    with k1 < 0: r_d = r (1 + k1 r^2) shrinks, then turns back, past r^2 = -1 / (3 k1)). Points that are not finite
    (an unseen reflector) are left out; a camera's share is NaN when none is finite.
    points: (frame, n, 3) world -> (camera,) in [0, 1]
    """
    flat = np.asarray(points, float).reshape(-1, 3)
    flat = flat[np.isfinite(flat).all(axis=1)]
    if not len(flat):
        return np.full(len(cams), np.nan)
    return np.array([1.0 - _seen(cam, flat).mean() for cam in cams])


def _seen(cam: Camera, points: np.ndarray) -> np.ndarray:
    """Whether ``cam`` sees each of ``points`` (see outside_share).  (n, 3) -> (n,) bool"""
    uv, z = cam.project(points)
    in_image = (uv[:, 0] >= 0) & (uv[:, 0] < cam.width) & (uv[:, 1] >= 0) & (uv[:, 1] < cam.height)
    rays = cam.pixel_rays()  # (y, x, 3) undistorted unit rays through the pixel centres
    tangents = rays[..., :2] / rays[..., 2:]
    lo, hi = tangents.reshape(-1, 2).min(axis=0), tangents.reshape(-1, 2).max(axis=0)
    local = cam.to_camera(points)
    with np.errstate(divide="ignore", invalid="ignore"):
        direction = local[:, :2] / local[:, 2:]
    margin = (hi - lo) / np.array([cam.width, cam.height])  # half a pixel either side of the outer centres
    in_field = np.all((direction >= lo - margin) & (direction <= hi + margin), axis=1)
    return (z > 0) & in_image & in_field

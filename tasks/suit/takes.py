"""Checkerboard-suit takes on the mesh body (Chen et al. 2021, §3 "Camera system"): the suit printed on Anny's
skin, filmed by a ring of grey machine-vision cameras.

``suit_rig`` puts 8-16 cameras on a circle around the volume at two alternating heights, in portrait, each
with its own small lens distortion, defocus and light level, aimed so that a standing body fills most of the
image height (about 1 px per mm at 3 m with the default 1536 x 2048 sensor, like the paper's 4000 x 2160 at 2 m).
``suit_texture`` prints the pattern (tasks/suit/pattern.py) as an albedo texture, pre-filtered so that one
ray per pixel samples a band-limited image (sharp square edges sampled at pixel centres would otherwise alias
the corners' sub-pixel positions). ``film`` renders frames [start, stop) of every camera and the ground truth:
each corner's 3D position, and per view its pixel, whether it is visible (in the image, facing the camera, not
hidden) and whether it is readable (a coded square it belongs to shows all four corners to the camera, at most
``readable_deg`` from face-on).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from mocapflow.tasks.shared.cameras import Camera
from mocapflow.tasks.shared.mesh_body import MeshBody
from mocapflow.tasks.shared.cameras import look_at, ring_positions
from mocapflow.tasks.studio.mesh_render import Lighting, MeshScene, film_view, surface_points, visibility
from mocapflow.tasks.suit.pattern import Suit, texture

SUIT_STUDIO_VERSION = "2+panels"
# Softboxes all around (§3 "Camera system": 32 of them): a strong diffuse term, two soft key lights, a dark room.
SOFTBOXES = Lighting(directions=((0.4, -0.6, 0.7), (-0.5, 0.8, 0.3)), intensities=(0.35, 0.25), ambient=0.55,
                     background=0.05)


class SuitTakeError(ValueError):
    """Settings a suit take cannot film with."""


@dataclass(frozen=True)
class SuitCameras:
    """The camera ring: ``count`` grey cameras, ``radius`` metres out, alternating between two heights."""

    count: int = 12
    width: int = 1536
    height: int = 2048
    radius: float = 3.0
    heights: tuple[float, float] = (0.7, 1.8)
    target: tuple[float, float, float] = (0.0, 0.0, 0.95)
    view_height_m: float = 2.3  # the height of the volume the image spans at the ring's radius
    distortion: float = 0.04  # |k1| at most, drawn per camera

    def __post_init__(self):
        if not 1 <= self.count <= 64 or self.width < 64 or self.height < 64 or self.radius <= 0.5:
            raise SuitTakeError(f"cameras need 1-64 views (got {self.count}), an image of at least 64 x 64 "
                                f"(got {self.width} x {self.height}) and a radius above 0.5 m (got {self.radius})")


@dataclass(frozen=True)
class SuitLook:
    """What the cameras see besides the geometry: sensor noise, defocus and the lights' spread across views."""

    noise: float = 1.0  # shot and read noise scale (0: none)
    blur_px: tuple[float, float] = (0.3, 0.7)  # Gaussian defocus sigma per view, drawn in this range
    light: tuple[float, float] = (0.8, 1.2)  # each view's light level, drawn in this range
    texture_px: int = 2048  # the printed texture's resolution (about one texel per image pixel)
    readable_deg: float = 70.0  # a square seen further from face-on than this is not readable


@dataclass(frozen=True)
class SuitRig:
    body: MeshBody
    suit: Suit
    cameras: tuple[Camera, ...]
    rays: tuple[np.ndarray, ...]  # per camera (y, x, 3) unit rays in the camera frame
    blur: np.ndarray  # (view,) defocus sigma, px
    light: np.ndarray  # (view,) light level
    texture: np.ndarray  # (t, t) float32 albedo
    look: SuitLook


def camera_names(count: int) -> list[str]:
    """The suit cameras' view names: ``cam00``, ``cam01``, ..."""
    return [f"cam{i:02d}" for i in range(count)]


def suit_cameras(spec: SuitCameras, rng: np.random.Generator) -> tuple[Camera, ...]:
    """The ring of grey cameras, the first facing the subject's front (+Y)."""
    names = camera_names(spec.count)
    pos = ring_positions(spec.count, spec.radius, 0.0)
    pos[:, 2] = np.resize(np.asarray(spec.heights, float), spec.count)
    f = spec.height * spec.radius / spec.view_height_m  # the volume's height fills the image at the ring
    cams = []
    for i, p in enumerate(pos):
        k1 = float(rng.uniform(-spec.distortion, spec.distortion))
        cx = (spec.width - 1) / 2 + rng.uniform(-8, 8)
        cy = (spec.height - 1) / 2 + rng.uniform(-8, 8)
        fi = f * rng.uniform(0.99, 1.01)
        cams.append(Camera(names[i], fi, fi, cx, cy, (k1, 0.0, 0.0, 0.0, 0.0), look_at(p, spec.target),
                           spec.width, spec.height))
    return tuple(cams)


def suit_texture(suit: Suit, resolution: int) -> np.ndarray:
    """The printed pattern, pre-filtered (Gaussian, 0.7 texel) for one ray per pixel.  -> (t, t) float32"""
    return cv2.GaussianBlur(texture(suit, resolution), (0, 0), 0.7)


def suit_rig(body: MeshBody, suit: Suit, cameras: SuitCameras, look: SuitLook, seed: int) -> SuitRig:
    printed = suit_texture(suit, look.texture_px)
    rng = np.random.default_rng([seed, 33])
    cams = suit_cameras(cameras, rng)
    return SuitRig(body, suit, cams, tuple(c.pixel_rays() for c in cams),
                   rng.uniform(*look.blur_px, len(cams)), rng.uniform(*look.light, len(cams)), printed, look)


@dataclass(frozen=True)
class SuitFrames:
    """Frames of a suit take: the images and the ground truth."""

    image: np.ndarray  # (view, frame, y, x) uint8
    corners: np.ndarray  # (frame, corner, 3) true 3D position, metres
    corners2d: np.ndarray  # (view, frame, corner, 2) true pixel (x, y), lens distortion included
    visible: np.ndarray  # (view, frame, corner) bool: in the image, facing the camera, not hidden
    readable: np.ndarray  # (view, frame, corner) bool: a coded square of the corner is wholly seen near face-on


def film(rig: SuitRig, vertices: np.ndarray, frames: range) -> SuitFrames:
    """Render ``frames`` of the posed meshes ``vertices`` (frame, vertex, 3) through every camera."""
    nv, n, nc = len(rig.cameras), len(frames), rig.suit.n_corners
    out = SuitFrames(np.zeros((nv, n, rig.cameras[0].height, rig.cameras[0].width), np.uint8),
                     np.zeros((n, nc, 3)), np.zeros((nv, n, nc, 2)), np.zeros((nv, n, nc), bool),
                     np.zeros((nv, n, nc), bool))
    lights = [_softboxes(float(k)) for k in rig.light]
    for i, f in enumerate(frames):
        verts = vertices[f]
        scene = MeshScene(verts, rig.body.faces)
        points, normals = surface_points(verts, rig.body.faces, rig.suit.corner_face, rig.suit.corner_bary)
        out.corners[i] = points
        for v, cam in enumerate(rig.cameras):
            if cam.width != rig.cameras[0].width or cam.height != rig.cameras[0].height:
                raise SuitTakeError(f"camera {cam.name!r} is {cam.width} x {cam.height}; every camera of a take "
                                    "films the same image size")
            out.image[v, i] = film_view(scene, cam, rig.rays[v], verts, rig.body.faces, rig.suit.face_uv, rig.texture,
                                        lights[v], np.random.default_rng([f, v, 7]), blur_px=float(rig.blur[v]),
                                        noise=rig.look.noise)
            xy, seen = visibility(scene, cam, points, normals)
            out.corners2d[v, i], out.visible[v, i] = xy, seen
            out.readable[v, i] = _readable(rig, cam, points, seen)
    return out


def _softboxes(k: float) -> Lighting:
    """The softboxes at a camera's light level ``k`` (its exposure: the background stays dark)."""
    return Lighting(SOFTBOXES.directions, tuple(x * k for x in SOFTBOXES.intensities), SOFTBOXES.ambient * k,
                    SOFTBOXES.background)


def _readable(rig: SuitRig, cam: Camera, points: np.ndarray, seen: np.ndarray) -> np.ndarray:
    """Corners of a coded square whose four corners are seen and whose normal is within readable_deg of the ray.
    points (corner, 3), seen (corner,) -> (corner,) bool"""
    quads = rig.suit.square_corners  # (square, 4)
    q = points[quads]  # (square, 4, 3)
    normal = np.cross(q[:, 2] - q[:, 0], q[:, 1] - q[:, 3])  # diagonals' cross: the squares' outward normals
    normal /= np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), 1e-12)
    to_cam = cam.cam_to_world[:3, 3] - q.mean(axis=1)
    to_cam /= np.linalg.norm(to_cam, axis=1, keepdims=True)
    facing = np.einsum("si,si->s", normal, to_cam) >= np.cos(np.radians(rig.look.readable_deg))
    ok = facing & seen[quads].all(axis=1)
    out = np.zeros(len(points), bool)
    out[quads[ok].ravel()] = True
    return out

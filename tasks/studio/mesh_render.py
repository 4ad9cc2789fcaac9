"""Ray casting the mesh body (Embree through embreex): per-pixel ground truth and a machine-vision camera's image.

``MeshScene`` holds one frame's posed mesh in an Embree BVH (built once per frame, shared by every view).
``cast_view`` sends one ray through every pixel centre (undistorted, so the image keeps the camera's lens
distortion) inside the mesh's projected bounding box and returns, per pixel, the face hit, its barycentric
coordinates (u, v: the point is (1-u-v) V0 + u V1 + v V2) and the camera-frame depth. ``grey_image`` shades
those hits as a lit, textured body (Lambert, directional lights and an ambient term, the texture read at the
interpolated UV), adds sensor noise and quantizes to 8 bits. ``surface_points`` places points given as
(face, barycentric, offset along the normal) on a posed mesh; ``visibility`` says which a camera sees.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from scipy import ndimage

from mocapflow.tasks.shared.cameras import Camera

NO_HIT = -1


@dataclass(frozen=True)
class Hits:
    """What each pixel's ray hits on the body."""

    face: np.ndarray  # (y, x) int32 face index, NO_HIT for none
    bary: np.ndarray  # (y, x, 2) float32 barycentric (u, v) of the hit
    depth: np.ndarray  # (y, x) float32 camera-frame z of the hit, metres; 0 where nothing is hit


@dataclass(frozen=True)
class Lighting:
    """Directional lights (world directions towards the light), their intensities and an ambient term."""

    directions: tuple[tuple[float, float, float], ...] = ((0.4, -0.6, 0.7), (-0.5, 0.8, 0.3))
    intensities: tuple[float, ...] = (0.75, 0.35)
    ambient: float = 0.15
    background: float = 0.08  # radiance of what no ray hits (a dark studio)


class MeshScene:
    """One frame's posed mesh, ready for ray queries."""

    def __init__(self, vertices: np.ndarray, faces: np.ndarray):
        from embreex import mesh_construction, rtcore_scene

        self.vertices = np.ascontiguousarray(vertices, dtype=np.float32)  # (vertex, 3)
        self.faces = np.ascontiguousarray(faces, dtype=np.int32)  # (face, 3)
        self._scene = rtcore_scene.EmbreeScene()
        mesh_construction.TriangleMesh(self._scene, self.vertices, self.faces)

    def cast(self, origins: np.ndarray, directions: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """First hit of each ray: face (n,) int32 (NO_HIT for none), barycentric (n, 2), distance along the ray (n,)."""
        out = self._scene.run(np.ascontiguousarray(origins, np.float32), np.ascontiguousarray(directions, np.float32),
                              output=1)
        face = out["primID"].astype(np.int32)
        miss = face < 0
        face[miss] = NO_HIT
        t = np.where(miss, np.inf, out["tfar"]).astype(np.float64)
        return face, np.column_stack([out["u"], out["v"]]).astype(np.float32), t


def _box(cam: Camera, vertices: np.ndarray, margin_px: int) -> tuple[int, int, int, int] | None:
    """Pixel box (y0, y1, x0, x1) around the projected mesh, or None when it is behind or outside the camera.

    The vertices' extent in normalized image coordinates (x/z, y/z), found without the lens, is a rectangle
    holding every vertex's undistorted image; points along its border are then put through the lens.
    """
    w2c = cam.world_to_cam
    pc = vertices @ w2c[:3, :3].T + w2c[:3, 3]  # (vertex, 3) camera frame
    front = pc[:, 2] > 1e-3
    if not front.any():
        return None
    xn, yn = pc[front, 0] / pc[front, 2], pc[front, 1] / pc[front, 2]
    s = np.linspace(0.0, 1.0, 9)
    x0, x1, y0, y1 = xn.min(), xn.max(), yn.min(), yn.max()
    border = np.concatenate([np.column_stack([x0 + (x1 - x0) * s, np.full(9, y)]) for y in (y0, y1)]
                            + [np.column_stack([np.full(9, x), y0 + (y1 - y0) * s]) for x in (x0, x1)])
    xy, _ = cv2.projectPoints(np.column_stack([border, np.ones(len(border))]), np.zeros(3), np.zeros(3), cam.K,
                              np.asarray(cam.dist))
    xy = xy.reshape(-1, 2)
    lo = np.floor(xy.min(axis=0)).astype(int) - margin_px
    hi = np.ceil(xy.max(axis=0)).astype(int) + margin_px + 1
    x0, y0 = max(lo[0], 0), max(lo[1], 0)
    x1, y1 = min(hi[0], cam.width), min(hi[1], cam.height)
    return None if x0 >= x1 or y0 >= y1 else (int(y0), int(y1), int(x0), int(x1))


def cast_view(scene: MeshScene, cam: Camera, rays: np.ndarray, margin_px: int = 4) -> Hits:
    """Per-pixel hits of ``cam``; ``rays`` = cam.pixel_rays() (y, x, 3), computed once per camera.

    Only the rays inside the mesh's projected bounding box (grown by ``margin_px``) are cast; the rest see
    nothing.
    """
    face = np.full((cam.height, cam.width), NO_HIT, np.int32)
    bary = np.zeros((cam.height, cam.width, 2), np.float32)
    depth = np.zeros((cam.height, cam.width), np.float32)
    box = _box(cam, scene.vertices, margin_px)
    if box is None:
        return Hits(face, bary, depth)
    y0, y1, x0, x1 = box
    local = rays[y0:y1, x0:x1].reshape(-1, 3)  # camera frame, unit
    rot, origin = cam.cam_to_world[:3, :3], cam.cam_to_world[:3, 3]
    f, b, t = scene.cast(np.broadcast_to(origin, local.shape), local @ rot.T)
    hit = f != NO_HIT
    face[y0:y1, x0:x1] = f.reshape(y1 - y0, x1 - x0)
    bary[y0:y1, x0:x1] = b.reshape(y1 - y0, x1 - x0, 2)
    depth[y0:y1, x0:x1] = np.where(hit, t * local[:, 2], 0.0).reshape(y1 - y0, x1 - x0)  # ray length -> camera z
    return Hits(face, bary, depth)


def vertex_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Area-weighted unit normals of a closed mesh's vertices.  (vertex, 3), (face, 3) -> (vertex, 3)"""
    v0, v1, v2 = (vertices[faces[:, k]] for k in range(3))
    face_n = np.cross(v1 - v0, v2 - v0)  # length = twice the area
    corners = faces.ravel()
    out = np.column_stack([np.bincount(corners, weights=np.repeat(face_n[:, c], 3), minlength=len(vertices))
                           for c in range(3)])
    return out / np.maximum(np.linalg.norm(out, axis=1, keepdims=True), 1e-12)


def interpolate(values: np.ndarray, face: np.ndarray, bary: np.ndarray) -> np.ndarray:
    """Per-corner values at barycentric points: values (face, 3, C), face (n,), bary (n, 2) -> (n, C)."""
    return barycentric(values[face], bary)


def barycentric(corners: np.ndarray, bary: np.ndarray) -> np.ndarray:
    """(1-u-v) c0 + u c1 + v c2: corners (n, 3, C), bary (n, 2) -> (n, C)."""
    u, v = bary[:, :1], bary[:, 1:]
    return (1 - u - v) * corners[:, 0] + u * corners[:, 1] + v * corners[:, 2]


def sample_texture(texture: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Bilinear texture look-up; texture (H, W) albedo in [0, 1], uv (n, 2) with v up -> (n,)."""
    h, w = texture.shape
    rows = (1.0 - uv[:, 1]) * h - 0.5  # texel centres at (i + 0.5) / size
    cols = uv[:, 0] * w - 0.5
    return ndimage.map_coordinates(texture, [rows, cols], order=1, mode="nearest")


def radiance(hits: Hits, vertices: np.ndarray, faces: np.ndarray, uv: np.ndarray, texture: np.ndarray,
             lighting: Lighting) -> np.ndarray:
    """Noise-free radiance of each pixel: texture albedo x (ambient + Lambert over the lights).  -> (y, x) float32"""
    out = np.full(hits.face.shape, lighting.background, np.float32)
    sel = hits.face != NO_HIT
    if not sel.any():
        return out
    face, bary = hits.face[sel], hits.bary[sel]
    normals = vertex_normals(vertices, faces)[faces]  # (face, 3, 3) per corner
    n = interpolate(normals, face, bary)
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
    albedo = sample_texture(texture, interpolate(uv, face, bary))
    light = np.full(len(face), lighting.ambient)
    for direction, intensity in zip(lighting.directions, lighting.intensities):
        d = np.asarray(direction, float) / np.linalg.norm(direction)
        light += intensity * np.clip(n @ d, 0.0, None)
    out[sel] = albedo * light
    return out


def grey_image(rad: np.ndarray, rng: np.random.Generator, noise: float = 1.0, gain: float = 200.0) -> np.ndarray:
    """8-bit sensor image of a radiance map: shot noise (Poisson in electrons at ``gain`` per unit radiance), read
    noise of 1.5 levels, both scaled by ``noise``.  (y, x) -> (y, x) uint8"""
    signal = np.clip(rad, 0.0, None) * gain
    if noise > 0:
        shot = np.sqrt(signal) * rng.standard_normal(signal.shape)
        signal = signal + noise * (shot + 1.5 * rng.standard_normal(signal.shape))
    return np.clip(np.rint(signal), 0, 255).astype(np.uint8)


def film_view(scene: MeshScene, cam: Camera, rays: np.ndarray, vertices: np.ndarray, faces: np.ndarray, uv: np.ndarray,
              texture: np.ndarray, lighting: Lighting, rng: np.random.Generator, *, blur_px: float | None = None,
              noise: float = 1.0) -> np.ndarray:
    """One camera's 8-bit image of the posed, textured body of ``scene``: a ray through every pixel (cast_view),
    shaded (radiance), blurred by the optics (a Gaussian of ``blur_px``, where given) and read by the sensor
    (grey_image).  rays: the camera's pixel rays; vertices (vertex, 3) and faces as posed -> (y, x) uint8"""
    rad = radiance(cast_view(scene, cam, rays), vertices, faces, uv, texture, lighting)
    if blur_px is not None:
        rad = cv2.GaussianBlur(rad, (0, 0), float(blur_px))
    return grey_image(rad, rng, noise)


def surface_points(vertices: np.ndarray, faces: np.ndarray, face: np.ndarray, bary: np.ndarray,
                   offset: np.ndarray | float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Points on a posed mesh given as (face, barycentric), moved ``offset`` metres along the surface normal.

    vertices (vertex, 3), faces (face, 3), face (n,), bary (n, 2), offset (n,) or scalar -> points (n, 3) and
    unit normals (n, 3) (interpolated vertex normals, pointing out of the body)
    """
    normals = vertex_normals(vertices, faces)
    p = interpolate(vertices[faces], face, bary)
    n = interpolate(normals[faces], face, bary)
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
    return p + np.asarray(offset, float).reshape(-1, 1) * n, n


def visibility(scene: MeshScene, cam: Camera, points: np.ndarray, normals: np.ndarray,
               tolerance_m: float = 2e-3) -> tuple[np.ndarray, np.ndarray]:
    """Pixel (distorted) and visibility of surface points seen by ``cam``: a point is visible when it projects
    into the image, faces the camera, and the body hides no part of the ray to it (a hit more than
    ``tolerance_m`` before the point).  points, normals (n, 3) -> xy (n, 2), visible (n,) bool
    """
    origin = cam.cam_to_world[:3, 3]
    to_point = points - origin
    dist = np.linalg.norm(to_point, axis=1)
    _, _, t = scene.cast(np.broadcast_to(origin, points.shape), to_point / dist[:, None])
    xy, z = cam.project(points)
    inside = (np.isfinite(xy).all(axis=1) & (z > 0) & (xy[:, 0] >= -0.5) & (xy[:, 0] < cam.width - 0.5)
              & (xy[:, 1] >= -0.5) & (xy[:, 1] < cam.height - 0.5))
    facing = np.einsum("ni,ni->n", normals, -to_point) > 0
    return xy, inside & facing & (t >= dist - tolerance_m)

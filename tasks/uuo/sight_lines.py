"""Sight lines past the mesh body, frame after frame: how many cameras see each point.

Embree (``mesh_render.MeshScene``) suits a frame filmed once by many pixels; counting the cameras that see a few
dozen markers on every frame of a take is a few hundred rays a frame, and there a new embree scene per frame costs
more than its rays (about 35 ms for the mesh body through embreex, whose mesh copy runs element by element). Here
one warp mesh is built once, its vertices replaced and its bounding-volume hierarchy refitted on each frame (about
a millisecond), and one kernel launch per frame casts every camera-to-point segment: a 300-frame take, 40 markers
and 8 cameras, in about 0.3 s on one core instead of 13 s (tests/tasks/uuo/test_uuo_takes.py checks the
counts against embree's). Warp runs on the CPU here on every machine, so counts do not depend on a GPU; its
kernel is compiled once per machine (a few seconds, cached under ``WARP_CACHE_PATH``, as Anny's skinning kernel).
"""

from __future__ import annotations

import numpy as np
import warp as wp

from mocapflow.tasks.shared.mesh_body import warp_ready

_DEVICE = "cpu"


@wp.kernel
def _count_clear(mesh: wp.uint64, cameras: wp.array(dtype=wp.vec3), points: wp.array2d(dtype=wp.vec3),
                 frame: int, tolerance: float, seen: wp.array2d(dtype=wp.int32)):
    """One thread per (camera, point): 1 where the segment from the camera to the point meets no triangle closer
    than ``tolerance`` short of the point."""
    c, m = wp.tid()
    origin = cameras[c]
    ray = points[frame, m] - origin
    dist = wp.length(ray)
    hit = wp.mesh_query_ray(mesh, origin, ray / dist, dist - tolerance)
    if not hit.result:
        wp.atomic_add(seen, frame, m, 1)


def cameras_seeing(vertices: np.ndarray, faces: np.ndarray, points: np.ndarray, cameras: np.ndarray,
                   tolerance_m: float = 2e-3) -> np.ndarray:
    """How many cameras see each point on each frame: the segment from the camera to the point meets the mesh
    nowhere closer than ``tolerance_m`` short of the point (a marker resting on the skin is not hidden by the skin
    under it). vertices (frame, vertex, 3), faces (face, 3), points (frame, point, 3), cameras (camera, 3)
    -> (frame, point) int64"""
    n_frames, n_points = points.shape[:2]
    if n_frames == 0 or n_points == 0 or len(cameras) == 0:
        return np.zeros((n_frames, n_points), np.int64)
    warp_ready()
    with wp.ScopedDevice(_DEVICE):
        mesh = wp.Mesh(points=wp.array(np.asarray(vertices[0], np.float32), dtype=wp.vec3),
                       indices=wp.array(np.asarray(faces, np.int32).ravel(), dtype=wp.int32))
        cams = wp.array(np.asarray(cameras, np.float32), dtype=wp.vec3)
        pts = wp.array(np.asarray(points, np.float32), dtype=wp.vec3)
        seen = wp.zeros((n_frames, n_points), dtype=wp.int32)
        for f in range(n_frames):
            if f:
                mesh.points.assign(np.asarray(vertices[f], np.float32))
                mesh.refit()
            wp.launch(_count_clear, dim=(len(cameras), n_points), inputs=[mesh.id, cams, pts, f, float(tolerance_m),
                                                                           seen])
        return seen.numpy().astype(np.int64)

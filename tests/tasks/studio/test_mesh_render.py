"""Ray casting the mesh body: known points through known cameras, occlusion, textures, determinism."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from mocapflow.tasks.shared import mesh_body as mb
from mocapflow.tasks.shared.cameras import Camera
from mocapflow.tasks.studio import mesh_render as mr
from mocapflow.tasks.shared.cameras import look_at


@pytest.fixture(scope="module")
def body():
    return mb.mesh_body(mb.random_phenotype(np.random.default_rng(31), 1.75))


def camera(position, target=(0.0, 0.0, 1.1), size=(640, 480), f=600.0, dist=(0.0,) * 5) -> Camera:
    w, h = size
    return Camera("cam", f, f, (w - 1) / 2 + 3.0, (h - 1) / 2 - 2.0, tuple(dist), look_at(position, target), w, h)


def rest_pose(body):
    return np.tile(np.eye(3), (1, len(body.bone_names), 1, 1))


def test_a_vertex_seen_by_a_camera_lands_on_its_own_surface_in_the_render(body):
    cam = camera((0.3, 2.5, 1.4), dist=(-0.12, 0.03, 0.001, -0.001, 0.0))
    scene = mr.MeshScene(body.vertices, body.faces)
    hits = mr.cast_view(scene, cam, cam.pixel_rays())
    normals = mr.vertex_normals(body.vertices, body.faces)
    xy, visible = mr.visibility(scene, cam, body.vertices, normals)
    view = cam.cam_to_world[:3, 3] - body.vertices
    facing = np.einsum("vi,vi->v", normals, view / np.linalg.norm(view, axis=1, keepdims=True)) > 0.5  # off the outline
    checked = 0
    for v in np.flatnonzero(visible & facing)[::97]:
        px = np.rint(xy[v]).astype(int)
        face = hits.face[px[1], px[0]]
        assert face != mr.NO_HIT
        hit = mr.interpolate(body.vertices[body.faces], np.array([face]), hits.bary[px[1], px[0]][None])[0]
        # the pixel centre is at most half a pixel from the vertex's projection: a few millimetres at 2.5 m
        assert np.linalg.norm(hit - body.vertices[v]) < 0.012
        assert hits.depth[px[1], px[0]] == pytest.approx(cam.to_camera(hit)[2], abs=1e-4)
        checked += 1
    assert checked > 30
    assert (hits.face != mr.NO_HIT).sum() > 10_000 and (hits.depth[hits.face == mr.NO_HIT] == 0).all()


def test_a_chest_point_is_hidden_when_the_forearm_crosses_in_front_of_it(body):
    cam = camera((0.0, 2.5, 1.2))
    crossed = rest_pose(body)
    arm = body.descendants("upperarm01.L")
    a = np.radians(-120)  # the left arm swung about the vertical to hang across the front of the body
    crossed[0, arm] = [[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]]
    posed = mb.pose_mesh(body, crossed, body.rest_heads[:1])
    forearm = 0.5 * (posed.heads[0, body.bone("lowerarm01.L")] + posed.heads[0, body.bone("wrist.L")])
    assert forearm[1] > body.rest_heads[body.bone("spine01"), 1]  # the forearm is in front of the chest

    # the point of the torso behind the forearm, found on the rest body where nothing is in the way
    rest_scene = mr.MeshScene(body.vertices, body.faces)
    origin = cam.cam_to_world[:3, 3]
    ray = (forearm - origin) / np.linalg.norm(forearm - origin)
    face, bary, _ = rest_scene.cast(origin[None], ray[None])
    point, normal = mr.surface_points(body.vertices, body.faces, face, bary)
    assert abs(point[0, 0]) < 0.2  # on the torso, not on an arm

    _, seen = mr.visibility(rest_scene, cam, point, normal)
    moved, moved_normal = mr.surface_points(posed.vertices[0], body.faces, face, bary)
    np.testing.assert_allclose(moved, point, atol=1e-6)  # the torso did not move
    _, hidden = mr.visibility(mr.MeshScene(posed.vertices[0], body.faces), cam, moved, moved_normal)
    assert seen[0] and not hidden[0]
    behind = camera((0.0, -2.5, 1.2))  # and the back camera never sees the chest
    assert not mr.visibility(rest_scene, behind, point, normal)[1][0]


def test_a_marker_off_the_skin_sits_along_the_normal():
    vertices = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0]])
    faces = np.array([[0, 1, 2]])
    p, n = mr.surface_points(vertices, faces, np.array([0, 0]), np.array([[0.2, 0.3], [0.0, 0.0]]), np.array([0.0095, 0]))
    np.testing.assert_allclose(p, [[0.2, 0.3, 0.0095], [0, 0, 0]], atol=1e-12)
    np.testing.assert_allclose(n, [[0, 0, 1], [0, 0, 1]], atol=1e-12)


def test_a_checkerboard_texture_shows_its_corners_where_the_uv_pattern_puts_them(body):
    squares = 16
    size = 1024
    yy, xx = np.mgrid[0:size, 0:size]
    texture = np.where(((yy * squares // size) + (xx * squares // size)) % 2 == 0, 0.9, 0.1)
    cam = camera((0.0, 1.4, 1.25), target=(0.0, 0.0, 1.2), size=(1280, 720), f=1400.0)
    scene = mr.MeshScene(body.vertices, body.faces)
    hits = mr.cast_view(scene, cam, cam.pixel_rays())
    image = mr.grey_image(mr.radiance(hits, body.vertices, body.faces, body.uv, texture, mr.Lighting()),
                          np.random.default_rng(0), noise=0.5)
    found = 0
    for corner in _corners_on_the_front(body, squares, scene, cam):
        xy = cam.project(corner[None])[0][0]
        start = (xy + 2.0).astype(np.float32).reshape(1, 1, 2)
        refined = cv2.cornerSubPix(image, start, (5, 5), (-1, -1), (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_COUNT, 40, 0.01))
        assert np.linalg.norm(refined.reshape(2) - xy) < 1.0
        found += 1
    assert found >= 5


def _corners_on_the_front(body, squares, scene, cam):
    """3D points of checker corners (UV multiples of 1/squares) on faces that face the camera squarely, away from
    UV seams (the four squares around the corner lie on one patch of the surface)."""
    locate = _UvLocator(body.uv.astype(float))
    centre = cam.cam_to_world[:3, 3]
    out = []
    for i in range(1, squares):
        for j in range(1, squares):
            target = np.array([i, j]) / squares
            ring = [locate(target + d) for d in ((0.01, 0.01), (-0.01, 0.01), (0.01, -0.01), (-0.01, -0.01))]
            here = locate(target)
            if here is None or any(r is None for r in ring):
                continue
            points, normals = mr.surface_points(body.vertices, body.faces, np.array([here[0]] + [r[0] for r in ring]),
                                                np.array([here[1]] + [r[1] for r in ring]))
            view = (centre - points[0]) / np.linalg.norm(centre - points[0])
            if np.linalg.norm(points[1:] - points[0], axis=1).max() > 0.03 or normals[0] @ view < 0.85:
                continue
            if mr.visibility(scene, cam, points[:1], normals[:1])[1][0]:
                out.append(points[0])
    return out


class _UvLocator:
    """(face, barycentric) of a UV point, or None when it lies in no face or in several (a seam). The faces' UV
    inverses are computed once; a point is solved only in the faces whose UV box holds it (a face outside the box
    cannot hold it, so the answer is that of solving every face)."""

    def __init__(self, uv):
        self.a, b, c = uv[:, 0], uv[:, 1], uv[:, 2]
        m = np.stack([b - self.a, c - self.a], axis=-1)  # (face, 2, 2)
        self.ok = np.abs(np.linalg.det(m)) > 1e-12
        self.inv = np.zeros_like(m)
        self.inv[self.ok] = np.linalg.inv(m[self.ok])
        pad = 1e-9  # the box a little wider than the face, against rounding at its edges
        self.low, self.high = uv.min(axis=1) - pad, uv.max(axis=1) + pad

    def __call__(self, target):
        near = np.flatnonzero(self.ok & (self.low <= target).all(axis=1) & (target <= self.high).all(axis=1))
        w = np.einsum("fij,fj->fi", self.inv[near], target - self.a[near])
        hits = np.flatnonzero((w >= 0).all(axis=1) & (w.sum(axis=1) <= 1))
        return (near[hits[0]], w[hits[0]]) if len(hits) == 1 else None


def test_the_same_seed_renders_the_same_bytes(body):
    cam = camera((1.5, 2.0, 1.5))
    texture = np.full((8, 8), 0.6)
    scene = mr.MeshScene(body.vertices, body.faces)
    images = [mr.grey_image(mr.radiance(mr.cast_view(scene, cam, cam.pixel_rays()), body.vertices, body.faces, body.uv,
                                        texture, mr.Lighting()), np.random.default_rng(seed)) for seed in (4, 4, 5)]
    assert np.array_equal(images[0], images[1]) and not np.array_equal(images[0], images[2])

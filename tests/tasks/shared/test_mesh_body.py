"""The mesh body (Anny) on the studio's axes: phenotypes, the rest mesh, skinning."""

from __future__ import annotations

import numpy as np
import pytest

from mocapflow.tasks.shared import mesh_body as mb


@pytest.fixture(scope="module")
def body():
    return mb.mesh_body(mb.random_phenotype(np.random.default_rng(11), 1.70))


def test_the_rest_mesh_stands_on_the_floor_at_the_asked_height(body):
    assert body.vertices.shape == (13718, 3) and body.faces.shape == (27420, 3)
    assert body.uv.shape == (27420, 3, 2) and 0.0 <= body.uv.min() and body.uv.max() <= 1.0
    assert body.vertices[:, 2].min() == pytest.approx(0.0, abs=1e-12)
    assert body.height == pytest.approx(1.70, abs=1e-6)


def test_the_body_faces_plus_y_with_its_left_side_at_minus_x_like_the_template(body):
    heads = {n: body.rest_heads[body.bone(n)] for n in ("foot.L", "toe3-1.L", "upperarm01.L", "upperarm01.R")}
    assert heads["toe3-1.L"][1] > heads["foot.L"][1] + 0.05  # the toes are ahead of the ankle
    assert heads["upperarm01.L"][0] < -0.1 < 0.1 < heads["upperarm01.R"][0]


def test_subjects_differ_by_seed_and_repeat_with_it():
    a, b = (mb.random_phenotype(np.random.default_rng(s)) for s in (1, 2))
    assert a != b and a == mb.random_phenotype(np.random.default_rng(1))
    tall, short = (mb.mesh_body(mb.random_phenotype(np.random.default_rng(5), h)) for h in (1.95, 1.55))
    assert tall.height == pytest.approx(1.95, abs=1e-6) and short.height == pytest.approx(1.55, abs=1e-6)
    for seed, height in ((8, 1.95), (0, 1.85), (8, 1.70)):  # subjects the line through the ends left 30-50 um off
        assert mb.mesh_body(mb.random_phenotype(np.random.default_rng(seed), height)).height \
            == pytest.approx(height, abs=1e-6)


def test_the_rest_rotations_give_back_the_rest_mesh_and_a_turn_moves_only_its_limb(body):
    n = len(body.bone_names)
    rest = np.tile(np.eye(3), (1, n, 1, 1))
    posed = mb.pose_mesh(body, rest, body.rest_heads[:1])
    np.testing.assert_allclose(posed.vertices[0], body.vertices, atol=1e-12)
    np.testing.assert_allclose(posed.heads[0], body.rest_heads, atol=1e-12)

    # the left forearm and everything below it turned 90 degrees about the elbow's vertical axis
    turn = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    elbow = body.bone("lowerarm01.L")
    below = body.descendants("lowerarm01.L")
    rot = rest.copy()
    rot[0, below] = turn
    moved = mb.pose_mesh(body, rot, body.rest_heads[:1])
    e = body.rest_heads[elbow]
    for b in below:  # bone heads turned rigidly about the elbow
        np.testing.assert_allclose(moved.heads[0, b], e + turn @ (body.rest_heads[b] - e), atol=1e-9)
    far = np.linalg.norm(body.vertices - e, axis=1) > 0.45  # the other side of the body does not move
    np.testing.assert_allclose(moved.vertices[0, far & (body.vertices[:, 0] > 0.1)],
                               body.vertices[far & (body.vertices[:, 0] > 0.1)], atol=1e-12)


def test_bad_phenotypes_and_poses_are_refused_with_the_fix(body):
    with pytest.raises(mb.MeshBodyError, match="weight = 1.5 is outside Anny's range"):
        mb.Phenotype(weight=1.5)
    with pytest.raises(mb.MeshBodyError, match="2.4 m is outside the studio's 1.5-2.0 m"):
        mb.random_phenotype(np.random.default_rng(0), 2.4)
    with pytest.raises(mb.MeshBodyError, match=r"rotations \(frame, 104, 3, 3\)"):
        mb.pose_mesh(body, np.zeros((2, 20, 3, 3)), np.zeros((2, 3)))
    with pytest.raises(mb.MeshBodyError, match="no bone 'elbow.L'"):
        body.bone("elbow.L")


def test_surface_layouts_cover_a_named_part_uniformly_by_area(body):
    faces, bary = mb.random_surface_points(body, np.random.default_rng(3), 4000, "left_forearm")
    part = body.part_faces("left_forearm")
    assert part[faces].all() and (bary >= 0).all() and (bary.sum(axis=1) <= 1).all()
    names = {body.bone_names[b] for b in body.vertex_bone[body.faces[faces]].ravel()}
    assert names <= {"lowerarm01.L", "lowerarm02.L"}
    # the part's faces split into two halves of equal area receive half the points each
    ids = np.flatnonzero(part)
    v = body.vertices[body.faces[ids]]
    area = 0.5 * np.linalg.norm(np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0]), axis=1)
    first = set(ids[np.cumsum(area) <= area.sum() / 2])
    share = np.mean([f in first for f in faces])
    assert abs(share - 0.5) < 0.03
    # the whole body's layout reaches every limb, and never the inside of the mouth or the eyes' backs
    faces, _ = mb.random_surface_points(body, np.random.default_rng(4), 3000)
    assert body.skin[faces].all()
    for limb in ("left_hand", "right_foot", "head", "right_shank"):
        assert body.part_faces(limb)[faces].any()
    with pytest.raises(mb.MeshBodyError, match="unknown body part 'tail'"):
        mb.random_surface_points(body, np.random.default_rng(0), 3, "tail")


def test_a_body_is_the_same_to_the_last_bit_whatever_the_thread_count(body):
    torch = pytest.importorskip("torch")
    threads = torch.get_num_threads()
    rot = np.tile(np.eye(3), (2, len(body.bone_names), 1, 1))
    rot[:, body.bone("lowerarm01.R")] = [[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]
    out = []
    try:
        for n in (1, 3):
            torch.set_num_threads(n)
            again = mb.mesh_body(body.phenotype)
            out.append((again.vertices, mb.pose_mesh(again, rot, np.tile(again.rest_heads[:1], (2, 1))).vertices))
    finally:
        torch.set_num_threads(threads)
    assert np.array_equal(out[0][0], out[1][0]) and np.array_equal(out[0][1], out[1][1])


def test_a_bones_descendants_are_its_limb(body):
    names = {body.bone_names[b] for b in body.descendants("lowerleg01.R")}
    assert {"lowerleg01.R", "lowerleg02.R", "foot.R", "toe1-1.R"} <= names
    assert not any(n.endswith(".L") or n.startswith(("upperleg", "spine")) for n in names)
    assert len(body.descendants("root")) == len(body.bone_names)

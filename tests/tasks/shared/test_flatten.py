"""Flattening: a developable piece unrolls without stretch, a curved one with little, orientation kept."""

from __future__ import annotations

import numpy as np
import pytest

from mocapflow.tasks.shared import flatten as fl


def grid_surface(nu: int, nv: int, lift) -> tuple[np.ndarray, np.ndarray]:
    """A triangulated grid over [0, 1]^2 mapped by ``lift`` (u, v) -> (n, 3), faces counter-clockwise from +z."""
    u, v = np.meshgrid(np.linspace(0, 1, nu), np.linspace(0, 1, nv), indexing="ij")
    vertices = lift(u.ravel(), v.ravel())
    idx = np.arange(nu * nv).reshape(nu, nv)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    return vertices, np.concatenate([np.column_stack([a, b, c]), np.column_stack([a, c, d])])


def half_cylinder(u, v):
    """Half a cylinder of radius 0.1 m, 0.5 m long: developable, 0.1 pi m around."""
    angle = np.pi * u
    return np.column_stack([0.1 * np.cos(angle), 0.1 * np.sin(angle), 0.5 * v])


def cap(u, v):
    """A piece of a sphere of radius 0.3 m, 0.3 m square seen from above: not developable."""
    x, y = (u - 0.5) * 0.3, (v - 0.5) * 0.3
    z = np.sqrt(0.3 ** 2 - x ** 2 - y ** 2)
    return np.column_stack([x, y, z])


def test_a_half_cylinder_unrolls_to_its_true_size_without_stretch():
    vertices, faces = grid_surface(20, 30, half_cylinder)
    uv = fl.arap(vertices, faces, fl.lscm(vertices, faces))
    s = fl.stretch(vertices, faces, uv)
    assert s.min() > 0.99 and s.max() < 1.01  # areas kept to 1 %
    # the unrolled sheet: 0.5 m long, as wide as the 19 chords of the arc
    width = 19 * 2 * 0.1 * np.sin(np.pi / 19 / 2)
    corners = uv[[0, 29, 19 * 30, 19 * 30 + 29]]  # (u, v) = (0, 0), (0, 1), (1, 0), (1, 1)
    assert np.linalg.norm(corners[1] - corners[0]) == pytest.approx(0.5, rel=0.01)
    assert np.linalg.norm(corners[2] - corners[0]) == pytest.approx(width, rel=0.01)
    assert np.linalg.norm(corners[3] - corners[0]) == pytest.approx(np.hypot(0.5, width), rel=0.01)
    edges = np.stack([faces, np.roll(faces, -1, axis=1)], axis=2).reshape(-1, 2)
    np.testing.assert_allclose(np.linalg.norm(uv[edges[:, 0]] - uv[edges[:, 1]], axis=1),
                               np.linalg.norm(vertices[edges[:, 0]] - vertices[edges[:, 1]], axis=1), rtol=0.01)


def test_a_curved_piece_is_flattened_with_less_area_stretch_than_the_conformal_map_alone():
    vertices, faces = grid_surface(25, 25, cap)
    conformal = fl.lscm(vertices, faces)
    rigid = fl.arap(vertices, faces, conformal)
    s_conformal, s_rigid = fl.stretch(vertices, faces, conformal), fl.stretch(vertices, faces, rigid)
    assert (s_rigid > 0).all() and (s_conformal > 0).all()  # faces keep their orientation: none flipped
    spread = lambda s: np.percentile(s, 99) / np.percentile(s, 1)  # noqa: E731
    assert spread(s_rigid) < 1.1 < spread(s_conformal)
    assert np.median(s_rigid) == pytest.approx(1.0, abs=0.03)


def test_a_mirrored_piece_is_laid_out_readable_from_its_outside():
    vertices, faces = grid_surface(10, 10, half_cylinder)
    flipped = faces[:, ::-1]  # the same piece seen from the other side
    assert (fl.stretch(vertices, faces, fl.lscm(vertices, faces)) > 0).all()
    assert (fl.stretch(vertices, flipped, fl.lscm(vertices, flipped)) > 0).all()


def test_closed_and_degenerate_pieces_are_refused():
    tetra = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], float)
    closed = np.array([[0, 2, 1], [0, 1, 3], [1, 2, 3], [0, 3, 2]])
    with pytest.raises(fl.FlattenError, match="no boundary"):
        fl.lscm(tetra, closed)
    with pytest.raises(fl.FlattenError, match="length zero"):
        fl.lscm(np.array([[0, 0, 0], [0, 0, 0], [0, 1, 0]], float), np.array([[0, 1, 2]]))

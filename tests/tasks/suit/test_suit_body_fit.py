"""The suit's body fit (Chen et al. 2021, §5): Anny posed by a known motion, surface points taken as corners, 40 %
hidden; the fit's skinned body must put the hidden ones back where they are."""

import numpy as np
import pytest

from mocapflow.tasks.shared import mesh_body as mb
from mocapflow.tasks.shared.kinematics import rodrigues, world_rotations
from mocapflow.tasks.shared.place_fit import PlaceFitError
from mocapflow.tasks.suit.body_fit import BodyFitConfig, BodyFitError, corner_weights, fit_body
from mocapflow.tasks.suit.fill import repose, skinning_transforms, unpose
from mocapflow.tasks.shared.solver_body import SolverBody

FRAMES = 5


@pytest.fixture(scope="module")
def take():
    """A body (not the fit's start phenotype) turning and bending steadily: each bone's local rotation is
    exp(f w_b) at frame f, the root moves along a line; 300 surface points, 40 % hidden per frame, and frame 2
    with only 10 points seen."""
    body = mb.mesh_body(mb.Phenotype(gender=0.3, weight=0.6, height=0.6))
    solver = SolverBody(body)
    rng = np.random.default_rng(11)
    rate = np.where(solver.seen_bones[:, None], rng.normal(0.0, 0.06, (len(body.bone_names), 3)), 0.0)
    rate[0] = [0.0, 0.0, 0.1]  # the root turns about the vertical
    f = np.arange(FRAMES)[:, None, None]
    local = rodrigues(f * rate[None])  # (frame, bone, 3, 3)
    root = body.rest_heads[0] + np.array([0.3, -0.2, 0.05]) + np.arange(FRAMES)[:, None] * [0.02, 0.01, 0.0]
    posed = mb.pose_mesh(body, world_rotations(local, body.bone_parents), root)
    face, bary = mb.random_surface_points(body, rng, 300)
    corners = body.faces[face]
    u, v = bary.T
    truth = (posed.vertices[:, corners] * np.column_stack([1 - u - v, u, v])[None, ..., None]).sum(2)
    hidden = rng.random(truth.shape[:2]) < 0.4
    hidden[2] = True
    hidden[2, rng.choice(300, 10, replace=False)] = False
    return solver, face, bary, truth, hidden


def test_the_fit_puts_hidden_points_back(take):
    solver, face, bary, truth, hidden = take
    result = fit_body(solver, np.where(hidden[..., None], np.nan, truth), face, bary, BodyFitConfig())
    np.testing.assert_array_equal(result.borrowed, np.arange(FRAMES) == 2)
    transforms = skinning_transforms(result.weights, result.bone_transforms)
    placed = repose(np.broadcast_to(result.rest, truth.shape), transforms)
    error = np.linalg.norm(placed - truth, axis=-1) * 1000.0  # mm
    fitted = ~result.borrowed
    assert np.median(error[fitted][hidden[fitted]]) < 1.0 and np.percentile(error[fitted][hidden[fitted]], 95) < 3.0
    assert np.median(error[2]) < 2.0  # the borrowed frame: its neighbours' pose, interpolated
    np.testing.assert_allclose(result.fit.phenotype, [0.3, 0.77, 0.5, 0.6, 0.6, 0.5], atol=0.01)  # the shape found
    assert abs(result.rest[:, 2].min()) < 0.3  # the rest frame stands on the floor (not at Anny's origin)
    np.testing.assert_allclose(unpose(placed, transforms), np.broadcast_to(result.rest, truth.shape), atol=1e-9)


def test_corner_weights_blend_the_vertices_weights(take):
    solver, face, bary, _, _ = take
    w = corner_weights(solver, face, bary)
    assert w.shape == (300, len(solver.body.bone_names)) and (w >= 0).all()
    np.testing.assert_allclose(w.sum(1), 1.0, atol=1e-6)
    at_vertex = corner_weights(solver, face[:1], np.array([[0.0, 0.0]]))[0]  # (u, v) = 0: the face's first vertex
    vertex = solver.body.faces[face[0], 0]
    expected = np.zeros(len(solver.body.bone_names))
    np.add.at(expected, solver.indices[vertex].numpy(), solver.weights[vertex].numpy())
    np.testing.assert_allclose(at_vertex, expected)


def test_bad_places_are_refused(take):
    solver, face, bary, truth, _ = take
    with pytest.raises(BodyFitError, match="barycentric"):
        fit_body(solver, truth, face, bary + 0.7)
    with pytest.raises(BodyFitError, match="faces"):
        fit_body(solver, truth, face + len(solver.body.faces), bary)
    with pytest.raises(BodyFitError, match=r"\(frame, corner, 3\)"):
        fit_body(solver, truth[:, :10], face, bary)
    with pytest.raises(BodyFitError, match="no frame has 30"):
        fit_body(solver, np.full_like(truth, np.nan), face, bary)
    with pytest.raises(PlaceFitError, match="out of range"):
        BodyFitConfig(min_points=2)

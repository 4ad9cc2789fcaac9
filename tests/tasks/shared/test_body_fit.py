"""The house's body fitter (Levenberg-Marquardt on Anny's rig): a known body recovered from points on its skin, a
solve landing where L-BFGS lands on the same energy once L-BFGS has converged, a local minimum of the whole energy
(every term on), and bad input refused."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from mocapflow.tasks.shared import body_fit as lm
from mocapflow.tasks.shared.kinematics import rodrigues
from mocapflow.tasks.shared.mesh_body import Phenotype, mesh_body
from mocapflow.tasks.shared.solver_body import BodyFit, SolverBody, posed_heads, posed_vertices
from mocapflow.tasks.uuo import fitting
from mocapflow.tasks.uuo.matching import skin_mask

FRAMES = 2
TRUE_PHENOTYPE = np.array([0.3, 0.6, 0.55, 0.6, 0.45, 0.5])


@pytest.fixture(scope="module")
def scene():
    """A body of a known pose and phenotype, 60 skin vertices as observations, and a start 0.15 rad off in every
    bone, 5 cm off at the root and at the default phenotype."""
    body = mesh_body(Phenotype())
    solver = SolverBody(body)
    rng = np.random.default_rng(4)
    seen = solver.seen_bones[:, None]
    local = rodrigues(np.where(seen, rng.normal(0.0, 0.25, (FRAMES, len(body.bone_names), 3)), 0.0))
    root = body.rest_heads[0] + rng.normal(0.0, 0.1, (FRAMES, 3))
    truth = BodyFit(local, root, TRUE_PHENOTYPE)
    vertices = rng.choice(np.flatnonzero(skin_mask(body)), 300, replace=False)
    points = posed_vertices(solver, truth, vertices)
    off = rodrigues(np.where(seen, rng.normal(0.0, 0.15, local.shape[:2] + (3,)), 0.0))
    start = BodyFit(local @ off, root + rng.normal(0.0, 0.05, root.shape), np.full(6, 0.5))
    return solver, truth, vertices, points, start


def _terms(solver, points, anchor, offset=0.0, floor=None, pose_weight=1e-3, shape_weight=1e-3):
    seen = np.ones(points.shape[:2])
    return lm.Terms(lm.Points(np.arange(points.shape[1]), points, seen, offset),
                    lm.PosePrior(anchor.local, np.full(len(points), pose_weight), root=True, form="chord"),
                    floor, np.asarray(anchor.phenotype, np.float64), shape_weight)


def test_a_known_body_is_recovered_from_points_on_its_skin(scene):
    solver, truth, vertices, points, start = scene
    places = lm.Places.of_vertices(vertices)
    solved = lm.solve_take(solver, places, _terms(solver, points, start, pose_weight=1e-9, shape_weight=1e-9),
                           lm.State.of(start), iterations=60, tolerance=1e-12).result()
    error = np.linalg.norm(posed_heads(solver, solved) - posed_heads(solver, truth), axis=-1)[:, solver.seen_bones]
    assert error.max() < 1e-3, error.max()  # every seen joint within a millimetre
    np.testing.assert_allclose(solved.phenotype, TRUE_PHENOTYPE, atol=0.01)
    assert np.abs(posed_vertices(solver, solved, vertices) - points).max() < 1e-4


def test_the_solve_lands_where_a_converged_lbfgs_lands(scene):
    """UUO's inverse kinematics (the marker offset, E_Theta, E_beta, the floor) on its own energy: L-BFGS run to
    convergence and Levenberg-Marquardt from the same start agree within a millimetre and on the energy."""
    solver, truth, vertices, points, start = scene
    floor = fitting.Floor(float(points[..., 2].min()) + 0.03, fitting.floor_vertices(solver.body))  # some contacts
    markers = points + 0.0095 * np.array([0.0, 0.6, 0.8])  # the marker's centre off the skin
    config = fitting.Weights(data=1.0, pose=0.1, shape=1.0, floor=10.0)
    data = lm.Points(np.arange(len(vertices)), markers, np.ones(markers.shape[:2]), 0.0095)
    terms = fitting.terms(solver, data, start, np.ones(FRAMES, bool), config, floor)
    places = lm.Places.of_vertices(vertices)
    ours = lm.solve_take(solver, places, terms, lm.State.of(start), iterations=100, tolerance=1e-12).result()

    import torch

    fit = fitting.Fit(solver, start, start, np.ones(FRAMES, bool))
    target, index = torch.from_numpy(markers), torch.from_numpy(vertices)

    def energy():  # tasks/uuo/ik's energy, written as it is there
        local, rots, heads, rest_vertices, rest_heads = fit.pose()
        d = torch.sqrt(((solver.skin(rots, heads, rest_vertices, rest_heads, index) - target) ** 2).sum(-1) + 1e-12)
        return ((d - 0.0095) ** 2).mean() + 0.1 * fit.pose_prior(local) + fit.shape_prior() \
            + 10.0 * fit.floor_energy(floor, rots, heads, rest_vertices, rest_heads)

    for _ in range(3):  # restarts: L-BFGS stops on a small change and starts its history afresh
        fitting.minimize(fit.parameters(), energy, 300)
    theirs = fit.result()
    assert lm.energy(solver, places, terms, ours) == pytest.approx(lm.energy(solver, places, terms, theirs), rel=1e-4)
    assert lm.energy(solver, places, terms, theirs) == pytest.approx(float(energy().detach()), rel=1e-9)
    gap = np.linalg.norm(posed_heads(solver, ours) - posed_heads(solver, theirs), axis=-1)[:, solver.seen_bones]
    assert gap.max() < 1e-3, gap.max()  # within a millimetre: the same minimum


def test_the_solve_ends_at_a_local_minimum_of_every_term(scene):
    """Points with an offset, E_Theta toward another pose, E_beta and the floor all on: no small change of the
    result's pose, root or phenotype lowers the energy."""
    solver, truth, vertices, points, start = scene
    floor = lm.FloorTerm(float(points[..., 2].min()) + 0.05, lm.Places.of_vertices(fitting.floor_vertices(
        solver.body)), 5.0)
    terms = _terms(solver, points, start, offset=0.005, floor=floor, pose_weight=1e-4, shape_weight=1e-2)
    places = lm.Places.of_vertices(vertices)
    solved = lm.solve_take(solver, places, terms, lm.State.of(start), iterations=100, tolerance=1e-12).result()
    best = lm.energy(solver, places, terms, solved)
    assert best < 0.5 * lm.energy(solver, places, terms, start)
    rng = np.random.default_rng(9)
    for _ in range(12):
        turn = rodrigues(np.where(solver.seen_bones[:, None], rng.normal(0.0, 1e-3, solved.local.shape[:2] + (3,)),
                                  0.0))
        moved = BodyFit(solved.local @ turn, solved.root + rng.normal(0.0, 1e-4, solved.root.shape),
                        np.clip(solved.phenotype + rng.normal(0.0, 1e-3, 6), 0.0, 1.0))
        assert lm.energy(solver, places, terms, moved) >= best * (1 - 1e-9)


def test_the_gradient_is_the_energy_s_own(scene):
    """Every term on (offset, E_Theta as the chord with the root, the floor with contacts, E_beta): the fitter's
    gradient against central differences of the energy, for the root's rotation and head, two limb bones' world
    rotations (about their heads, their children carried along) and the phenotype."""
    from mocapflow.tasks.shared.kinematics import world_rotations

    solver, truth, vertices, points, start = scene
    fit = BodyFit(start.local, start.root, np.array([0.37, 0.58, 0.46, 0.43, 0.53, 0.62]))  # off the knots of
    # Anny's piecewise linear blend shapes, where one-sided and central differences part
    soles = fitting.floor_vertices(solver.body)
    height = float(np.median(posed_vertices(solver, fit, soles)[0, :, 2]))  # half the floor's places in contact
    floor = lm.FloorTerm(height, lm.Places.of_vertices(soles), 5.0)
    terms = _terms(solver, points + 0.003, truth, offset=0.0095, floor=floor, pose_weight=1e-3, shape_weight=1e-2)
    places = lm.Places.of_vertices(vertices)
    pose, shape = lm.gradient(solver, places, terms, fit)
    seen = np.flatnonzero(solver.seen_bones)
    world = world_rotations(fit.local, solver.body.bone_parents)
    eps = 1e-6

    def moved(bone: int, axis: int, step: float) -> BodyFit:
        delta = np.zeros(3)
        delta[axis] = step
        local = fit.local.copy()
        parent = solver.body.bone_parents[bone]
        frame = world[0, parent] if bone else np.eye(3)
        local[0, bone] = rodrigues(frame.T @ delta) @ local[0, bone]  # L_b <- exp(M_parent^T delta) L_b
        return BodyFit(local, fit.root, fit.phenotype)

    for bone in (0, solver.body.bone("upperarm01.L"), solver.body.bone("lowerleg01.R")):
        column = 3 * int(np.searchsorted(seen, bone))
        for axis in range(3):
            numeric = (lm.energy(solver, places, terms, moved(bone, axis, eps))
                       - lm.energy(solver, places, terms, moved(bone, axis, -eps))) / (2 * eps)
            assert pose[0, column + axis] == pytest.approx(numeric, rel=1e-5, abs=1e-9)
    for axis in range(3):
        shift = np.zeros((FRAMES, 3))
        shift[0, axis] = eps
        numeric = (lm.energy(solver, places, terms, BodyFit(fit.local, fit.root + shift, fit.phenotype))
                   - lm.energy(solver, places, terms, BodyFit(fit.local, fit.root - shift, fit.phenotype))) / (2 * eps)
        assert pose[0, 3 * len(seen) + axis] == pytest.approx(numeric, rel=1e-5, abs=1e-9)
    for k in range(6):
        step = np.zeros(6)
        step[k] = 1e-5
        numeric = (lm.energy(solver, places, terms, BodyFit(fit.local, fit.root, fit.phenotype + step))
                   - lm.energy(solver, places, terms, BodyFit(fit.local, fit.root, fit.phenotype - step))) / 2e-5
        assert shape[k] == pytest.approx(numeric, rel=1e-4, abs=1e-7)


def test_poses_alone_keep_the_phenotype_and_bad_terms_are_refused(scene):
    solver, truth, vertices, points, start = scene
    places = lm.Places.of_vertices(vertices)
    known = dataclasses.replace(start, phenotype=TRUE_PHENOTYPE)
    solved = lm.solve_poses(solver, places, _terms(solver, points, known, pose_weight=1e-9), lm.State.of(known),
                            iterations=60, tolerance=1e-12, chunk=2).result()
    np.testing.assert_array_equal(solved.phenotype, TRUE_PHENOTYPE)
    assert np.abs(posed_vertices(solver, solved, vertices) - points).max() < 1e-3
    good = _terms(solver, points, start)
    with pytest.raises(lm.FitError, match="target"):
        lm.solve_take(solver, places, dataclasses.replace(good, points=dataclasses.replace(
            good.points, target=points[:, :10])), lm.State.of(start))
    with pytest.raises(lm.FitError, match="index 300 places"):
        lm.solve_poses(solver, places, dataclasses.replace(good, points=dataclasses.replace(
            good.points, place=np.arange(300) + 1)), lm.State.of(start))
    with pytest.raises(lm.FitError, match="form"):
        lm.solve_poses(solver, places, dataclasses.replace(good, prior=dataclasses.replace(
            good.prior, form="euler")), lm.State.of(start))
    with pytest.raises(lm.FitError, match="shape_anchor"):
        lm.solve_take(solver, places, dataclasses.replace(good, shape_anchor=None), lm.State.of(start))

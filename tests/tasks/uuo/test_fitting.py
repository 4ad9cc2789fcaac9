"""The solver's floor (beyond the paper): the plane found from the markers, and the term that keeps the skin
above it."""

from __future__ import annotations

import numpy as np
import pytest

from mocapflow.tasks.shared.mesh_body import Phenotype, mesh_body
from mocapflow.tasks.shared.solver_body import BodyFit, SolverBody, posed_vertices
from mocapflow.tasks.uuo.fitting import Fit, Floor, floor_vertices, minimize
from mocapflow.tasks.uuo.pose_fit import PoseFitConfig
from mocapflow.tasks.uuo.solve import floor_plane


def test_the_floor_is_the_ground_plane_unless_the_markers_go_below_it():
    rng = np.random.default_rng(0)
    markers = rng.uniform([-1, -1, 0.02], [1, 1, 1.7], (40, 30, 3))
    markers[3, 4] = np.nan
    assert floor_plane(markers, 0.0095) == 0.0  # markers above z = 0: the calibrated ground
    low = markers - [0, 0, 0.5]  # a file whose origin lies half a metre above the floor
    expected = np.percentile(low[..., 2][np.isfinite(low[..., 2])], 1.0) - 0.0095
    assert floor_plane(low, 0.0095) == pytest.approx(expected) and expected < -0.45


def test_the_floor_term_lifts_a_sunken_body_onto_the_floor_and_no_higher():
    import torch

    body = mesh_body(Phenotype())
    solver = SolverBody(body)
    index = floor_vertices(body)
    soles = body.vertices[index, 2] < body.vertices[:, 2].min() + 0.04
    assert 20 <= soles.sum() and 20 <= (~soles).sum()  # the soles and the skin spread over the body
    n = 3
    local = np.broadcast_to(np.eye(3), (n, len(body.bone_names), 3, 3)).copy()
    root = np.tile(body.rest_heads[0], (n, 1)) - [0.0, 0.0, 0.2]  # standing 20 cm into the floor
    start = BodyFit(local, root, np.array([0.5, 0.77, 0.5, 0.5, 0.5, 0.5]))
    fit = Fit(solver, start, start, np.ones(n, bool))
    floor = Floor(0.0, index)
    with torch.no_grad():
        below = float(fit.floor_energy(floor, *fit.pose()[1:]))
        assert below > 0.2 ** 2 * soles.sum() * 0.5  # every sole about 20 cm deep
        assert float(fit.floor_energy(None, *fit.pose()[1:])) == 0.0

    sunk = torch.from_numpy(root)

    weight = PoseFitConfig().floor_weight

    def energy():  # the floor against a pull back to where the body started (as the markers pull in a solve)
        _, rots, heads, rest_vertices, rest_heads = fit.pose()
        return weight * fit.floor_energy(floor, rots, heads, rest_vertices, rest_heads) \
            + ((fit.root - sunk) ** 2).sum(-1).mean()

    minimize([fit.root], energy, 50)
    lowest = posed_vertices(solver, fit.result(), index)[..., 2].min(axis=1)
    assert ((lowest > -0.005) & (lowest < 0.0)).all(), lowest  # lifted onto the floor, not above it


def test_the_solvers_settings_are_checked():
    from mocapflow.tasks.uuo.ik import IKConfig, IKError
    from mocapflow.tasks.uuo.pose_fit import PoseFitError

    with pytest.raises(IKError, match="lbfgs where smooth_weight"):
        IKConfig(smooth_weight=0.1)  # the smoothing term couples frames: L-BFGS only
    assert IKConfig(smooth_weight=0.1, solver="lbfgs").solver == "lbfgs"
    with pytest.raises(PoseFitError, match="solver"):
        PoseFitConfig(solver="newton")
    with pytest.raises(PoseFitError, match="steps"):
        PoseFitConfig(solver="lm", steps=0)

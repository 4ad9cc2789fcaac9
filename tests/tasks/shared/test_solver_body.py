"""The solvers' body: Anny's rig in torch skins a body over a take exactly as the mesh studio poses it."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from mocapflow.tasks.shared import mesh_body as mb
from mocapflow.tasks.shared.kinematics import local_rotations
from mocapflow.tasks.shared.solver_body import BodyFit, SolverBody, posed_vertices


@pytest.fixture(scope="module")
def body():
    b = mb.mesh_body(mb.Phenotype(gender=0.2, height=0.7))
    return b, SolverBody(b)


def test_the_solver_body_skins_like_anny(body):
    import torch

    b, solver = body
    rng = np.random.default_rng(0)
    world = Rotation.from_rotvec(rng.normal(0, 0.4, (3 * len(b.bone_names), 3))).as_matrix().reshape(3, -1, 3, 3)
    root = rng.normal(0, 0.3, (3, 3)) + [0.0, 0.0, 1.0]
    posed = mb.pose_mesh(b, world, root)
    fit = BodyFit(local_rotations(world, b.bone_parents), root,
                  np.array([getattr(b.phenotype, k) for k in mb.PHENOTYPE_NAMES]))
    chosen = np.arange(0, len(b.vertices), 97)
    np.testing.assert_allclose(posed_vertices(solver, fit, chosen), posed.vertices[:, chosen], atol=1e-9)
    per_frame = torch.from_numpy(rng.integers(0, len(b.vertices), (3, 5)))  # a different vertex set per frame
    rest_v, rest_h = solver.rest(torch.from_numpy(fit.phenotype))
    rots, heads = solver.kinematics(torch.from_numpy(fit.local), torch.from_numpy(root), rest_h)
    np.testing.assert_allclose(solver.skin(rots, heads, rest_v, rest_h, per_frame).numpy(),
                               np.take_along_axis(posed.vertices, per_frame.numpy()[..., None], 1), atol=1e-9)
    np.testing.assert_allclose(heads.numpy(), posed.heads, atol=1e-9)

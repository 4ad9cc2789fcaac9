"""The solvers' body: Anny's rig as a differentiable function of pose and shape, evaluated where it is needed.

UUO fits a parametric body to markers (Milef et al. 2024, §3.5) and the checkerboard suit fills its holes on
one (Chen et al. 2021); here the body is Anny (tasks/shared/mesh_body). ``BodyFit`` is a body over a take
(each bone's local rotation and the root's head per frame, one phenotype); ``posed_vertices`` and
``posed_heads`` evaluate one.
Anny poses all 13,718 vertices per call; the solver needs a few dozen per frame (the vertex each marker sample
is assigned to) over a whole take, and its gradient. ``SolverBody`` holds the rig in torch tensors and evaluates
the same skinning as ``mesh_body.pose_mesh`` (tests check it to 1e-9 m) on any subset of vertices:

- forward kinematics in Anny's 'world-orient' form, one vectorized step per depth of the tree:
  ``M_b = M_parent(b) L_b`` (world rotation from the bone's rest orientation), ``h_b = h_parent +
  M_parent (r_b - r_parent)`` (bone heads follow their parents; r the rest heads);
- linear blend skinning: ``v = sum_k w_k (M_k (v_rest - r_k) + h_k)`` over each vertex's nine bone weights;
- shape from the phenotype through Anny's blend shapes (differentiable), so the rest vertices and heads are
  functions of six numbers.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mocapflow.tasks.shared.mesh_body import FACING, PHENOTYPE_NAMES, MeshBody, anny_model

# Bones a marker can tell about: everything but the fingers, toes and face (their rotations stay the prior's).
_UNSEEN_PREFIXES = ("finger", "toe", "metacarpal", "eye", "jaw", "tongue", "special", "orbicularis", "levator",
                    "oris", "risorius", "temporalis", "cheek", "nose")


def torch_rodrigues(rotvec):
    """Rotation matrices of rotation vectors, differentiable at zero.  (..., 3) -> (..., 3, 3)"""
    import torch

    theta2 = (rotvec ** 2).sum(-1, keepdim=True)[..., None]  # (..., 1, 1)
    small = theta2 < 1e-10
    theta = torch.sqrt(torch.where(small, torch.ones_like(theta2), theta2))
    a = torch.where(small, 1.0 - theta2 / 6.0, torch.sin(theta) / theta)  # sin θ / θ
    b = torch.where(small, 0.5 - theta2 / 24.0, (1.0 - torch.cos(theta)) / theta2.clamp_min(1e-10))  # (1 - cos θ) / θ²
    x, y, z = rotvec.unbind(-1)
    zero = torch.zeros_like(x)
    k = torch.stack([zero, -z, y, z, zero, -x, -y, x, zero], -1).reshape(rotvec.shape[:-1] + (3, 3))
    eye = torch.eye(3, dtype=rotvec.dtype, device=rotvec.device)
    return eye + a * k + b * (k @ k)  # Rodrigues' formula


class SolverBody:
    """Anny's rig in torch: rest shape from a phenotype, forward kinematics, skinning of chosen vertices.

    Holds arrays only; no IO. ``body`` gives the topology (the same for every phenotype).
    """

    def __init__(self, body: MeshBody):
        import torch

        model = anny_model()
        self.body = body
        self.parents = body.bone_parents
        self.n_bones = len(body.bone_names)
        self.weights = model.vertex_bone_weights.to(torch.float64)  # (vertex, 9)
        self.indices = model.vertex_bone_indices.long()  # (vertex, 9)
        depth = np.zeros(self.n_bones, np.int64)
        for b in range(1, self.n_bones):  # parents come first
            depth[b] = depth[self.parents[b]] + 1
        self.levels = [(torch.from_numpy(np.flatnonzero(depth == d)), torch.from_numpy(self.parents[depth == d]))
                       for d in range(1, depth.max() + 1)]
        self.seen_bones = np.array([not n.startswith(_UNSEEN_PREFIXES) for n in body.bone_names])
        self.facing = torch.from_numpy(FACING)
        self._rests: dict[bytes, tuple] = {}  # phenotype -> rest(), the last few (rest_fixed)

    def rest(self, phenotype):
        """Rest vertices (vertex, 3) and rest bone heads (bone, 3) in the studio's axes (unlifted) for a phenotype
        tensor (6,) in PHENOTYPE_NAMES order; differentiable in it."""
        model = anny_model()
        kwargs = {name: phenotype[i:i + 1] for i, name in enumerate(PHENOTYPE_NAMES)}
        out = model(phenotype_kwargs=kwargs)
        return out["rest_vertices"][0] @ self.facing.T, out["rest_bone_poses"][0, :, :3, 3] @ self.facing.T

    def rest_fixed(self, phenotype: np.ndarray):
        """``rest`` of a fixed phenotype, without gradients, the last four kept: part matching and the screens pose
        one prior hundreds of times, and Anny's blend shapes cost more than the skinning."""
        import torch

        key = np.asarray(phenotype, np.float64).tobytes()
        if key not in self._rests:
            with torch.no_grad():
                self._rests[key] = self.rest(torch.from_numpy(np.asarray(phenotype, np.float64)))
            if len(self._rests) > 4:
                self._rests.pop(next(iter(self._rests)))
        return self._rests[key]

    def kinematics(self, local, root, rest_heads):
        """World rotations and heads.  local (frame, bone, 3, 3), root (frame, 3), rest_heads (bone, 3)
        -> (frame, bone, 3, 3), (frame, bone, 3)"""
        import torch

        rots = local.clone()
        heads = torch.zeros(local.shape[:2] + (3,), dtype=local.dtype)
        heads[:, 0] = root
        for bones, up in self.levels:  # one vectorized step per depth
            rots[:, bones] = rots[:, up] @ local[:, bones]
            offset = rest_heads[bones] - rest_heads[up]  # (k, 3)
            heads[:, bones] = heads[:, up] + (rots[:, up] @ offset[..., None])[..., 0]
        return rots, heads

    def skin(self, rots, heads, rest_vertices, rest_heads, vertices):
        """Posed positions of chosen vertices.  rots (frame, bone, 3, 3), heads (frame, bone, 3), vertices: index
        tensor (n,) the same every frame, or (frame, n) per frame -> (frame, n, 3)"""
        import torch

        w, idx = self.weights[vertices], self.indices[vertices]  # (..., n, 9)
        local = rest_vertices[vertices][..., None, :] - rest_heads[idx]  # (..., n, 9, 3)
        if vertices.dim() == 1:
            m = rots[:, idx]  # (frame, n, 9, 3, 3)
            h = heads[:, idx]  # (frame, n, 9, 3)
        else:
            f = torch.arange(rots.shape[0])[:, None, None]
            m, h = rots[f, idx], heads[f, idx]
        moved = (m @ local[..., None])[..., 0] + h  # (frame, n, 9, 3)
        return (w[..., None] * moved).sum(-2)  # Eq. of linear blend skinning, as Anny's kernel

    def dense_weights(self, vertices: np.ndarray):
        """Each chosen vertex's weight on every bone.  (n,) -> (n, bone) tensor"""
        import torch

        index = torch.from_numpy(np.asarray(vertices, np.int64))
        out = torch.zeros(len(index), self.n_bones, dtype=torch.float64)
        return out.scatter_add_(1, self.indices[index], self.weights[index])

    def skin_dense(self, rots, heads, rest_points, rest_heads, dense):
        """Posed positions of rest points with their bone weights, as ``skin``: sum_k w_k (M_k (x - r_k) + h_k)
        = (sum_k w_k M_k) x - sum_k w_k (M_k r_k - h_k), two matrix products over the bones (no gather).
        rest_points (n, 3), dense (n, bone) -> (frame, n, 3)"""
        frames, bones = rots.shape[:2]
        blend = (dense @ rots.reshape(frames, bones, 9)).reshape(frames, -1, 3, 3)
        carried = (rots @ rest_heads[..., None])[..., 0] - heads  # (frame, bone, 3)
        return (blend @ rest_points[..., None])[..., 0] - dense @ carried


@dataclass(frozen=True)
class BodyFit:
    local: np.ndarray  # (frame, bone, 3, 3) local rotations (root: world)
    root: np.ndarray  # (frame, 3) root head, metres
    phenotype: np.ndarray  # (6,) Anny's phenotype, mesh_body.PHENOTYPE_NAMES order


def posed_vertices(body: SolverBody, fit: BodyFit, vertices: np.ndarray, chunk: int = 64) -> np.ndarray:
    """Skinned positions of chosen vertices over the take.  -> (frame, n, 3)"""
    import torch

    rest_vertices, rest_heads = body.rest_fixed(fit.phenotype)
    with torch.no_grad():
        out = []
        dense = body.dense_weights(vertices)
        points = rest_vertices[torch.from_numpy(np.asarray(vertices, np.int64))]
        for s in range(0, fit.root.shape[0], chunk):
            rots, heads = body.kinematics(torch.from_numpy(fit.local[s:s + chunk]),
                                          torch.from_numpy(fit.root[s:s + chunk]), rest_heads)
            out.append(body.skin_dense(rots, heads, points, rest_heads, dense).numpy())
    return np.concatenate(out)


def posed_heads(body: SolverBody, fit: BodyFit) -> np.ndarray:
    """Every bone's head over the take.  -> (frame, bone, 3)"""
    import torch

    _, rest_heads = body.rest_fixed(fit.phenotype)
    with torch.no_grad():
        return body.kinematics(torch.from_numpy(fit.local), torch.from_numpy(fit.root), rest_heads)[1].numpy()

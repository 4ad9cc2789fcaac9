"""What UUO's solver stages optimize (Milef et al. 2024, §3.5): a body over a whole take, relative to a reference.

A ``BodyFit`` (tasks/shared/solver_body) is a body over a take: each bone's local rotation and the root's head
per frame, one phenotype. ``Fit`` makes one differentiable around a start: per frame a rotation vector for every
bone a marker can tell about (applied after the start's local rotation), the take's extra rotation of the root
(the yaw offset b of §3.5.1), the root's head per frame and the phenotype (Anny's shape, for SMPL's beta). Its
regularizers are the paper's, against an anchor body (the prior, or the previous stage's result in the
refinement): E_Theta (Eq. 5), the mean squared rotation of each bone from the anchor's (2 (1 - cos angle) per
bone, the squared angle for small ones, over its three parameters), zero on frames the prior lost, and E_beta
(Eq. 2), the mean squared departure from the anchor's phenotype. Beyond the paper, a ``Floor`` keeps the skin
above the floor plane (``floor_energy``: the squared depth below it of a fixed set of skin vertices, the soles
among them, summed per frame). ``minimize`` runs L-BFGS with strong Wolfe line search (§3.6) on any energy of it.

``terms`` states the same energy for the house's Levenberg-Marquardt fitter (tasks/shared/body_fit), which inverse
kinematics and the refinement use by default (the pose fit stays on L-BFGS, measured better): its terms are sums, so the means above become weights (the chamfer's over the samples kept,
E_Theta's over the held bones' three parameters and the valid frames, E_beta's over the six phenotype values, the
floor's over the frames). The yaw offset b is not a parameter there: the root's rotation is free per frame, and b
only changes L-BFGS's path, not the energy.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mocapflow.tasks.shared import body_fit as lm
from mocapflow.tasks.shared.solver_body import BodyFit, SolverBody, torch_rodrigues
from mocapflow.tasks.uuo.matching import evenly, skin_mask

SOLE_HEIGHT_M = 0.04  # rest vertices this low are the soles and toes
SOLVERS = ("lm", "lbfgs")  # the house's Levenberg-Marquardt fitter, or L-BFGS on the energy (§3.6)
LM_TOLERANCE = 1e-5  # relative energy decrease at which a Levenberg-Marquardt solve stops


@dataclass(frozen=True)
class Floor:
    """The floor plane z = ``height`` (m) and the skin vertices kept above it (the soles, then evenly spread)."""

    height: float
    vertices: np.ndarray  # (n,) vertex indices


def floor_vertices(body, count: int = 48) -> np.ndarray:
    """``count`` skin vertices of the soles and toes and ``count`` spread over the whole skin (rest mesh, evenly
    by index).  body: MeshBody -> (n,)"""
    skin = skin_mask(body)
    soles = np.flatnonzero(skin & (body.vertices[:, 2] < body.vertices[:, 2].min() + SOLE_HEIGHT_M))
    return np.unique(np.concatenate([evenly(soles, count), evenly(np.flatnonzero(skin), count)]))


class Fit:
    """A BodyFit as torch parameters around a reference (see the module's text)."""

    def __init__(self, body: SolverBody, start: BodyFit, anchor: BodyFit, valid: np.ndarray):
        import torch

        self.body = body
        self.seen = torch.from_numpy(np.flatnonzero(body.seen_bones))
        n_frames = start.root.shape[0]
        self.start_local = torch.from_numpy(start.local)
        self.anchor_local = torch.from_numpy(anchor.local[:, body.seen_bones])
        self.anchor_phenotype = torch.from_numpy(np.asarray(anchor.phenotype, np.float64))
        self.valid = torch.from_numpy(valid.astype(np.float64))  # (frame,) weight of E_Theta
        self.delta = torch.zeros((n_frames, len(self.seen), 3), dtype=torch.float64, requires_grad=True)
        self.turn = torch.zeros(3, dtype=torch.float64, requires_grad=True)
        self.root = torch.tensor(start.root, dtype=torch.float64, requires_grad=True)
        self.phenotype = torch.tensor(np.asarray(start.phenotype, np.float64), requires_grad=True)

    def parameters(self, shape: bool = True) -> list:
        return [self.delta, self.turn, self.root] + ([self.phenotype] if shape else [])

    def local(self):
        """Local rotations (frame, bone, 3, 3)."""
        local = self.start_local.clone()
        local[:, self.seen] = self.start_local[:, self.seen] @ torch_rodrigues(self.delta)
        local[:, 0] = torch_rodrigues(self.turn) @ local[:, 0]  # §3.5.1: the yaw offset b, one for the take
        return local

    def pose(self):
        """Local rotations, world rotations (frame, bone, 3, 3), heads (frame, bone, 3), rest vertices, rest heads."""
        local = self.local()
        rest_vertices, rest_heads = self.body.rest(self.phenotype.clamp(0.0, 1.0))
        rots, heads = self.body.kinematics(local, self.root, rest_heads)
        return local, rots, heads, rest_vertices, rest_heads

    def pose_prior(self, local):
        """E_Theta, Eq. (5): each bone's squared rotation from the anchor, per parameter, over valid frames."""
        relative = self.anchor_local.transpose(-1, -2) @ local[:, self.seen]  # (frame, seen bone, 3, 3)
        angle2 = 2.0 * (1.0 - (relative.diagonal(dim1=-2, dim2=-1).sum(-1) - 1.0) / 2.0)  # 2 (1 - cos a) ~ a^2
        per_frame = angle2.mean(1) / 3.0
        return (per_frame * self.valid).sum() / self.valid.sum().clamp_min(1.0)

    def floor_energy(self, floor: Floor | None, rots, heads, rest_vertices, rest_heads):
        """The squared depth (m^2) of ``floor.vertices`` below the floor, summed over them, mean over frames."""
        import torch

        if floor is None:
            return torch.zeros((), dtype=torch.float64)
        v = self.body.skin(rots, heads, rest_vertices, rest_heads, torch.from_numpy(floor.vertices))
        return (torch.relu(floor.height - v[..., 2]) ** 2).sum(-1).mean()

    def shape_prior(self):
        return ((self.phenotype - self.anchor_phenotype) ** 2).mean()  # E_beta, Eq. (2)

    def result(self) -> BodyFit:
        import torch

        with torch.no_grad():
            return BodyFit(self.local().numpy(), self.root.detach().numpy().copy(),
                           self.phenotype.detach().clamp(0.0, 1.0).numpy().copy())


def minimize(parameters: list, energy, iterations: int) -> float:
    """L-BFGS with strong Wolfe line search (§3.6) on ``energy()``; the last energy."""
    import torch

    opt = torch.optim.LBFGS(parameters, lr=1.0, max_iter=iterations, history_size=20,
                            line_search_fn="strong_wolfe", tolerance_grad=1e-9, tolerance_change=1e-12)

    def closure():
        opt.zero_grad()
        value = energy()
        value.backward()
        return value

    return float(opt.step(closure).detach())


@dataclass(frozen=True)
class Weights:
    """The energy's weights as the stages state them (the means of ``Fit``'s terms)."""

    data: float  # lambda_3D or lambda_M, on the mean squared distance of the samples kept
    pose: float  # lambda_Theta
    shape: float  # lambda_beta
    floor: float  # on the floor's mean over frames


def terms(body: SolverBody, data: lm.Points, anchor: BodyFit, valid: np.ndarray, weights: Weights,
          floor: Floor | None) -> lm.Terms:
    """``Fit``'s energy as the body fitter's sums: ``data``'s weight the samples kept (1 or 0), scaled here."""
    frames = data.target.shape[0]
    kept = max(float(data.weight.sum()), 1.0)
    held = 3 * int(body.seen_bones.sum())  # E_Theta: the mean over the seen bones' three parameters, root included
    points = lm.Points(data.place, data.target, weights.data * data.weight / kept, data.offset)
    prior = lm.PosePrior(anchor.local, weights.pose * valid.astype(np.float64) / (held * max(valid.sum(), 1.0)),
                         root=True, form="chord")  # Eq. (5): 2 (1 - cos angle)
    ground = lm.FloorTerm(floor.height, lm.Places.of_vertices(floor.vertices), weights.floor / frames) \
        if floor is not None and weights.floor else None
    return lm.Terms(points, prior, ground, np.asarray(anchor.phenotype, np.float64), weights.shape / 6.0)  # Eq. (2)


def solve_lm(body: SolverBody, places: lm.Places, energy: lm.Terms, start: BodyFit, steps: int,
             skin: lm.Skin | None = None) -> BodyFit:
    """Levenberg-Marquardt on pose and shape from ``start`` (the body fitter's ``solve_take``)."""
    return lm.solve_take(body, places, energy, lm.State.of(start), steps, LM_TOLERANCE, skin).result()

"""Stages 4 and 5 of UUO's mocap solver: inverse kinematics on the found correspondences and its refinement
(Milef et al. 2024, §3.5.4-3.5.5).

With each labelled trajectory tied to one skin vertex, the body is fitted to the markers (Eq. 7): every marker's
distance to its vertex should be the marker offset delta = 9.5 mm (Eq. 8), while E_Theta and E_beta hold it to an
anchor: the prior in stage 4, stage 4's result in the refinement (stage 5, after stage 3 is run again). A small
optional term on the second differences of the bone heads (``smooth_weight``, off in the paper) damps jitter;
another keeps the skin above the floor (``floor_weight``, fitting.Floor; not in the paper). The house's
Levenberg-Marquardt fitter solves it (``solver: lm``, ``steps``); ``solver: lbfgs`` runs L-BFGS for ``iterations``,
the smoothing term's only solver.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mocapflow.tasks.shared.solver_body import BodyFit, SolverBody
from mocapflow.tasks.shared import body_fit as lm
from mocapflow.tasks.uuo.fitting import SOLVERS, Fit, Floor, Weights, minimize, solve_lm, terms


class IKError(ValueError):
    """Settings or correspondences inverse kinematics cannot use."""


@dataclass(frozen=True)
class IKConfig:
    marker_weight: float = 1.0  # lambda_M (§3.6)
    pose_weight: float = 0.1  # lambda_Theta
    shape_weight: float = 1.0  # lambda_beta
    smooth_weight: float = 0.0  # on the bone heads' second differences, m^2 (not in the paper)
    offset_m: float = 0.0095  # delta of Eq. (8)
    iterations: int = 100  # L-BFGS's
    floor_weight: float = 10.0  # on the skin's squared depth below the floor (not in the paper)
    solver: str = "lm"  # lm (the house's body fitter) | lbfgs: chosen on a tuning split (benchmarks/uuo_fitter.py)
    steps: int = 30  # Levenberg-Marquardt's, at most

    def __post_init__(self):
        if min(self.marker_weight, self.pose_weight, self.shape_weight, self.smooth_weight, self.offset_m,
               self.floor_weight) < 0 \
                or min(self.iterations, self.steps) < 1:
            raise IKError(f"inverse kinematics settings out of range: weights, offset >= 0, iterations, steps >= 1 "
                          f"({self})")
        if self.solver not in SOLVERS or (self.solver == "lm" and self.smooth_weight):
            raise IKError(f"inverse kinematics solver must be one of {SOLVERS}, and lbfgs where smooth_weight > 0 "
                          f"(got {self.solver!r}, smooth_weight {self.smooth_weight})")


def inverse_kinematics(body: SolverBody, markers: np.ndarray, vertex: np.ndarray, start: BodyFit, anchor: BodyFit,
                       valid: np.ndarray, config: IKConfig, floor: Floor | None = None) -> BodyFit:
    """markers (frame, marker, 3); vertex (marker,) each trajectory's vertex, -1 for none; ``floor``: the plane
    the skin stays above (none: no floor term)."""
    import torch

    labelled = np.flatnonzero(vertex >= 0)
    if not len(labelled):
        raise IKError("no marker has a vertex to fit (every trajectory unlabelled); check the markers and the prior")
    m = markers[:, labelled]
    if config.solver == "lm":  # Eq. (7)-(8) and the floor as the body fitter's sums
        seen = np.isfinite(m).all(-1).astype(np.float64)
        data = lm.Points(np.arange(len(labelled)), np.nan_to_num(m), seen, config.offset_m)
        weights = Weights(config.marker_weight, config.pose_weight, config.shape_weight, config.floor_weight)
        return solve_lm(body, lm.Places.of_vertices(vertex[labelled]),
                        terms(body, data, anchor, valid, weights, floor), start, config.steps)
    seen = torch.from_numpy(np.isfinite(m).all(-1).astype(np.float64))  # (frame, labelled)
    target = torch.from_numpy(np.nan_to_num(m))
    index = torch.from_numpy(vertex[labelled])
    fit = Fit(body, start, anchor, valid)
    bones = torch.from_numpy(np.flatnonzero(body.seen_bones))

    def energy():
        local, rots, heads, rest_vertices, rest_heads = fit.pose()
        v = body.skin(rots, heads, rest_vertices, rest_heads, index)  # (frame, labelled, 3)
        d = torch.sqrt(((v - target) ** 2).sum(-1) + 1e-12)
        e_m = ((d - config.offset_m) ** 2 * seen).sum() / seen.sum().clamp_min(1.0)  # Eq. (8)
        value = config.marker_weight * e_m + config.pose_weight * fit.pose_prior(local) \
            + config.shape_weight * fit.shape_prior() \
            + config.floor_weight * fit.floor_energy(floor, rots, heads, rest_vertices, rest_heads)  # Eq. (7), floor
        if config.smooth_weight and heads.shape[0] > 2:
            h = heads[:, bones]
            value = value + config.smooth_weight * ((h[2:] - 2 * h[1:-1] + h[:-2]) ** 2).sum(-1).mean()
        return value

    minimize(fit.parameters(), energy, config.iterations)
    return fit.result()

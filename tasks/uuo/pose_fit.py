"""Stage 2 of UUO's mocap solver: pose fitting by chamfer distance (Milef et al. 2024, §3.5.2).

The body (pose, the take's yaw offset b, root translation, shape) is fitted to the unlabelled markers: every
marker sample is pulled toward its closest skin vertex of the matched chain (the one-directional chamfer of
Eq. 1), while E_Theta (Eq. 5) and E_beta (Eq. 2) hold the body near the prior (Eq. 4). The closest vertices
are found again between rounds of L-BFGS (iterated closest points), on an evenly spaced subset of the
chain's skin; samples farther than ``outlier_m`` from every vertex (ghosts, a marker off the chain) are left
out of the round, the bound shrinking over the rounds. The marker's centre sits ``offset_m`` above the
skin, so the distance term is (|v - m| - offset)^2 rather than |v - m|^2. Beyond the paper, the skin is kept
above the floor (``floor_weight``, fitting.Floor). L-BFGS runs ``iterations`` per round (``solver: lbfgs``, the
default: on the tuning split it ends nearer the truth than the house's Levenberg-Marquardt fitter, which goes all
the way to each round's closest points, wrong ones included; ``solver: lm``, ``steps`` per round).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mocapflow.tasks.shared.solver_body import BodyFit, SolverBody, posed_vertices
from mocapflow.tasks.shared import body_fit as lm
from mocapflow.tasks.uuo.fitting import SOLVERS, Fit, Floor, Weights, minimize, solve_lm, terms
from mocapflow.tasks.uuo.matching import closest, evenly, part_vertices


class PoseFitError(ValueError):
    """Settings pose fitting cannot use."""


@dataclass(frozen=True)
class PoseFitConfig:
    chamfer_weight: float = 10.0  # lambda_3D (§3.6)
    pose_weight: float = 1.0  # lambda_Theta
    shape_weight: float = 1.0  # lambda_beta
    offset_m: float = 0.0095  # the marker's centre above the skin
    vertices: int = 3000  # skin vertices of the chain the closest points are searched among
    rounds: int = 5  # closest-point assignments
    iterations: int = 20  # L-BFGS iterations per round
    outlier_m: tuple[float, float] = (0.3, 0.06)  # farthest sample kept, first round to last
    core_rounds: int = 2  # first rounds on the trunk alone (torso, hips, head), from the trunk outward
    core_outlier_m: float = 0.1  # farthest sample kept in those rounds
    floor_weight: float = 10.0  # on the skin's squared depth below the floor (not in the paper)
    solver: str = "lbfgs"  # lbfgs | lm (the house's body fitter): chosen on a tuning split (benchmarks/uuo_fitter.py)
    steps: int = 10  # Levenberg-Marquardt's per round, at most

    def __post_init__(self):
        if self.solver not in SOLVERS or self.steps < 1:
            raise PoseFitError(f"pose fitting's solver is one of {SOLVERS} with steps >= 1 (got {self.solver!r}, "
                               f"{self.steps})")
        if min(self.chamfer_weight, self.pose_weight, self.shape_weight, self.offset_m, self.floor_weight) < 0 \
                or self.rounds < 1 \
                or self.iterations < 1 or self.vertices < 10 or not 0 < self.outlier_m[1] <= self.outlier_m[0]:
            raise PoseFitError(f"pose fitting settings out of range: weights and offset >= 0, rounds, iterations "
                               f">= 1, vertices >= 10, 0 < outlier_m[1] <= outlier_m[0] (got {self})")


def fit_pose(body: SolverBody, markers: np.ndarray, start: BodyFit, anchor: BodyFit, valid: np.ndarray,
             chain: np.ndarray, config: PoseFitConfig, floor: Floor | None = None) -> BodyFit:
    """Stage 2 for one hypothesis.  markers (frame, marker, 3) NaN where unseen; chain (n,) candidate vertices;
    ``floor``: the plane the skin stays above (none: no floor term)."""
    import torch

    index = evenly(chain, config.vertices)
    core = np.isin(index, part_vertices(body.body, ("torso", "hips", "head")))
    seen = np.isfinite(markers).all(-1)
    filled = np.where(seen[..., None], markers, 0.0)
    trunk = [config.core_outlier_m] * (config.core_rounds if core.sum() >= 10 else 0)
    bounds = trunk + list(np.geomspace(*config.outlier_m, config.rounds))
    places = lm.Places.of_vertices(index)
    skin = lm.skin_of(body, lm.place_weights(body, places)) if config.solver == "lm" else None
    fit = Fit(body, start, anchor, valid) if config.solver == "lbfgs" else None
    current = start
    for r, bound in enumerate(bounds):
        nearest, d2 = closest(filled, posed_vertices(body, current, index))
        keep = seen & (d2 < bound ** 2)
        if r < len(trunk):  # the trunk first: samples whose closest vertex is on it, within the trunk's bound
            keep &= core[nearest]
        if fit is None:  # Eq. (1), (4) and the floor as the body fitter's sums
            data = lm.Points(nearest, filled, keep.astype(np.float64), config.offset_m)
            weights = Weights(config.chamfer_weight, config.pose_weight, config.shape_weight, config.floor_weight)
            current = solve_lm(body, places, terms(body, data, anchor, valid, weights, floor), current, config.steps,
                               skin)
        else:
            _lbfgs_round(body, fit, torch.from_numpy(filled), keep, index[nearest], config, floor)
            current = fit.result()
    return current


def _lbfgs_round(body: SolverBody, fit: Fit, target, keep: np.ndarray, assigned: np.ndarray, config: PoseFitConfig,
                 floor: Floor | None) -> None:
    """One round of L-BFGS on Eq. (4) with the round's closest vertices."""
    import torch

    keep = torch.from_numpy(keep.astype(np.float64))  # (frame, marker)
    assigned = torch.from_numpy(assigned)  # (frame, marker) vertex of each sample

    def energy():
        local, rots, heads, rest_vertices, rest_heads = fit.pose()
        v = body.skin(rots, heads, rest_vertices, rest_heads, assigned)  # (frame, marker, 3)
        d = torch.sqrt(((v - target) ** 2).sum(-1) + 1e-12)
        chamfer = ((d - config.offset_m) ** 2 * keep).sum() / keep.sum().clamp_min(1.0)  # Eq. (1), offset
        return (config.chamfer_weight * chamfer + config.pose_weight * fit.pose_prior(local)
                + config.shape_weight * fit.shape_prior()  # Eq. (4)
                + config.floor_weight * fit.floor_energy(floor, rots, heads, rest_vertices, rest_heads))

    minimize(fit.parameters(), energy, config.iterations)

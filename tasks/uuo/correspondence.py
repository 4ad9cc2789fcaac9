"""Stage 3 of UUO's mocap solver: marker-vertex correspondence (Milef et al. 2024, §3.5.3, Eq. 6).

Each marker trajectory gets the skin vertex of the fitted body with the least mean distance to it over the
frames it is seen. A trajectory seen in fewer than ``min_frames`` frames, or whose best vertex stays more
than ``reject_m`` beyond the marker offset on average (a ghost, a reflection), gets no vertex (-1): it is left
unlabelled and out of the inverse kinematics.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mocapflow.tasks.shared.solver_body import BodyFit, SolverBody, posed_vertices


class CorrespondenceError(ValueError):
    """Settings the correspondence cannot use."""


@dataclass(frozen=True)
class CorrespondenceConfig:
    offset_m: float = 0.0095
    reject_m: float = 0.1  # mean distance beyond the offset above which a trajectory stays unlabelled
    min_frames: int = 5  # trajectories seen in fewer frames stay unlabelled

    def __post_init__(self):
        if self.offset_m < 0 or self.reject_m <= 0 or self.min_frames < 1:
            raise CorrespondenceError(f"correspondence needs offset_m >= 0, reject_m > 0 and min_frames >= 1, "
                                      f"got {self}")


def mean_distances(markers: np.ndarray, vertices: np.ndarray) -> np.ndarray:
    """Mean over the frames each marker is seen of its distance to every vertex (inf for an unseen marker).
    markers (frame, marker, 3), vertices (frame, vertex, 3) -> (marker, vertex)"""
    import torch

    seen = np.isfinite(markers).all(-1)
    total = torch.zeros((markers.shape[1], vertices.shape[1]), dtype=torch.float64)
    for f in range(markers.shape[0]):
        have = np.flatnonzero(seen[f])
        if len(have):
            total[have] += torch.cdist(torch.from_numpy(markers[f, have]), torch.from_numpy(vertices[f]))
    count = seen.sum(0)
    return np.where(count[:, None] > 0, total.numpy() / np.maximum(count, 1)[:, None], np.inf)


def correspond(body: SolverBody, markers: np.ndarray, fit: BodyFit, chain: np.ndarray,
               config: CorrespondenceConfig) -> tuple[np.ndarray, np.ndarray]:
    """Eq. (6): each trajectory's vertex (-1: none) and its mean distance (m).  markers (frame, marker, 3)"""
    distances = mean_distances(markers, posed_vertices(body, fit, chain))  # (marker, vertex)
    best = distances.argmin(1)
    mean = distances[np.arange(len(best)), best]
    ok = (np.isfinite(markers).all(-1).sum(0) >= config.min_frames) & (mean <= config.offset_m + config.reject_m)
    return np.where(ok, chain[best], -1), mean

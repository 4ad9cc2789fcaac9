"""Hiding observed corners to score the hole filling (Chen et al. 2021, §5; the issue's "hidden observations").

Real captures have no truth where the suit is hidden, so the filling is scored where it is known: a seeded share
of the observed corners is hidden for runs of frames (as an occluding limb would), the filling runs on what is
left, and its estimate at the hidden corners is compared with their triangulated (or, in the studio, true)
positions. ``hidden`` marks them.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import xarray as xr


class HoldoutError(ValueError):
    """Settings that cannot hide corners."""


@dataclass(frozen=True)
class HoldoutConfig:
    share: float = 0.1  # of the corners, each hidden for one run
    run_frames: tuple[int, int] = (5, 30)  # a hidden run's length, drawn in this range
    seed: int = 0

    def __post_init__(self):
        lo, hi = self.run_frames
        if not 0 < self.share <= 1 or not 1 <= lo <= hi:
            raise HoldoutError(f"share must be in (0, 1] (got {self.share}) and run_frames a range 1 <= low <= high "
                               f"(got {self.run_frames})")


def hidden_runs(observed: np.ndarray, config: HoldoutConfig) -> np.ndarray:
    """Which observations to hide: ``share`` of the corners, each over one run of frames.
    observed (frame, corner) bool -> (frame, corner) bool, a subset of observed."""
    rng = np.random.default_rng([config.seed, 5])
    n_frames, n_corners = observed.shape
    hide = np.zeros_like(observed)
    chosen = rng.choice(n_corners, size=int(round(config.share * n_corners)), replace=False)
    lengths = rng.integers(config.run_frames[0], config.run_frames[1] + 1, size=len(chosen))
    starts = rng.integers(0, np.maximum(n_frames - lengths + 1, 1))
    for c, start, length in zip(chosen, starts, lengths):
        hide[start:start + length, c] = True
    return hide & observed


def hide_corners(points: xr.Dataset, config: HoldoutConfig) -> xr.Dataset:
    """Task: suit_points with a share of its observations hidden (NaN) and marked in ``hidden``."""
    position = points["position"].transpose("frame", "corner", "xyz").values.copy()
    hide = hidden_runs(np.isfinite(position).all(axis=-1), config)
    position[hide] = np.nan
    kept = points["kept"].transpose("frame", "view", "corner").values & ~hide[:, None, :]
    return points.assign(position=(("frame", "corner", "xyz"), position),
                         kept=(("frame", "view", "corner"), kept),
                         hidden=(("frame", "corner"), hide),
                         hidden_position=(("frame", "corner", "xyz"),
                                          np.where(hide[..., None], points["position"].values, np.nan)
                                          .astype(np.float32)))

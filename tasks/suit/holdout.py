"""Hiding observed corners to score the hole filling (Chen et al. 2021, §5; the issue's "hidden observations").

Real captures have no truth where the suit is hidden, so the filling is scored where it is known: a seeded share
of the observed corners is hidden for runs of frames, the filling runs on what is left, and its estimate at the
hidden corners is compared with their triangulated (or, in the studio, true) positions. ``hidden`` marks them.

Two shapes of hole: ``random`` hides single corners, each for one run, their neighbours still observed (the
easiest hole to fill); ``patch`` hides what an occluding limb or prop hides: every corner within a radius (drawn
in ``radius_m``) of a corner, for a run of frames, the patch following the body, patches added until ``share``
of the observations are hidden.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import xarray as xr


class HoldoutError(ValueError):
    """Settings that cannot hide corners."""


SHAPES = ("random", "patch")


@dataclass(frozen=True)
class HoldoutConfig:
    share: float = 0.1  # random: of the corners, each hidden for one run; patch: of the observations
    run_frames: tuple[int, int] = (5, 30)  # a hidden run's length, drawn in this range
    seed: int = 0
    shape: str = "random"  # or "patch": holes shaped like occlusions
    radius_m: tuple[float, float] = (0.06, 0.15)  # a patch's radius on the body, drawn in this range

    def __post_init__(self):
        lo, hi = self.run_frames
        if not 0 < self.share <= 1 or not 1 <= lo <= hi:
            raise HoldoutError(f"share must be in (0, 1] (got {self.share}) and run_frames a range 1 <= low <= high "
                               f"(got {self.run_frames})")
        if self.shape not in SHAPES:
            raise HoldoutError(f"shape {self.shape!r} is not a hole shape; shapes: {', '.join(SHAPES)}")
        if not 0 < self.radius_m[0] <= self.radius_m[1] <= 2:
            raise HoldoutError(f"radius_m must be a range 0 < low <= high <= 2 m, got {self.radius_m}")


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


def hidden_patches(position: np.ndarray, config: HoldoutConfig, max_patches: int = 100_000) -> np.ndarray:
    """Which observations to hide: patches of the suit, each every corner within a drawn radius of a drawn corner
    for a run of frames (measured frame by frame where the centre corner is, or was last seen), until ``share`` of
    the observations are hidden.  position (frame, corner, 3), NaN where unobserved -> (frame, corner) bool"""
    rng = np.random.default_rng([config.seed, 6])
    observed = np.isfinite(position).all(axis=-1)
    n_frames = len(position)
    hide = np.zeros_like(observed)
    seen = np.argwhere(observed)  # (observation, 2) frame, corner: where a patch may be centred
    goal = config.share * len(seen)
    for _ in range(max_patches):
        if hide.sum() >= goal or not len(seen):
            break
        frame, centre = seen[rng.integers(len(seen))]
        length = int(rng.integers(config.run_frames[0], config.run_frames[1] + 1))
        radius = rng.uniform(*config.radius_m)
        where = position[frame, centre]
        for f in range(frame, min(frame + length, n_frames)):
            if observed[f, centre]:
                where = position[f, centre]
            near = np.linalg.norm(np.nan_to_num(position[f] - where, nan=np.inf), axis=1) <= radius
            hide[f] |= near
    return hide & observed


def hide_corners(points: xr.Dataset, config: HoldoutConfig) -> xr.Dataset:
    """Task: suit_points with a share of its observations hidden (NaN) and marked in ``hidden``."""
    position = points["position"].transpose("frame", "corner", "xyz").values.copy()
    observed = np.isfinite(position).all(axis=-1)
    hide = hidden_patches(position, config) if config.shape == "patch" else hidden_runs(observed, config)
    position[hide] = np.nan
    kept = points["kept"].transpose("frame", "view", "corner").values & ~hide[:, None, :]
    return points.assign(position=(("frame", "corner", "xyz"), position),
                         kept=(("frame", "view", "corner"), kept),
                         hidden=(("frame", "corner"), hide),
                         hidden_position=(("frame", "corner", "xyz"),
                                          np.where(hide[..., None], points["position"].values, np.nan)
                                          .astype(np.float32)))

"""Labels from the studio's truth: the suit's 3D half (triangulation, hole filling) on perfect 2D labels.

A stand-in for the 2D chain (corners, quads, codes, labels) when only the 3D stages are under study: every corner
the truth calls readable in a view is labelled at its true pixel plus Gaussian noise of ``noise_px`` (the paper's
CornerdetNet localises to 0.21 px on its test set), and a seeded share is mislabelled (moved to another corner's
pixel), as a RecogNet error would. Figures made with it measure the 3D stages, never the 2D chain.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import xarray as xr


class OracleError(ValueError):
    """Settings or inputs the truth-labelling stand-in cannot use."""


@dataclass(frozen=True)
class OracleConfig:
    noise_px: float = 0.2  # Gaussian sigma of each label's pixel
    wrong: float = 0.0  # share of labels moved to another corner's true pixel (a misread code)
    seed: int = 0

    def __post_init__(self):
        if self.noise_px < 0 or not 0 <= self.wrong < 1:
            raise OracleError(f"noise_px must be >= 0 (got {self.noise_px}) and wrong in [0, 1) (got {self.wrong})")


def noisy_labels(truth: np.ndarray, readable: np.ndarray, config: OracleConfig, rng: np.random.Generator) -> np.ndarray:
    """truth (frame, corner, 2) true pixels, readable (frame, corner) -> labels (frame, corner, 2), NaN unlabelled."""
    out = np.where(readable[..., None], truth + config.noise_px * rng.standard_normal(truth.shape), np.nan)
    for f in range(len(out)):
        seen = np.flatnonzero(readable[f])
        wrong = seen[rng.random(len(seen)) < config.wrong]
        if len(wrong) and len(seen) > 1:
            donors = rng.choice(seen, size=len(wrong))
            out[f, wrong] = np.where((donors == wrong)[:, None], np.nan, truth[f, donors])
    return out


def oracle_labels(images: xr.Dataset, config: OracleConfig) -> xr.Dataset:
    """Task: suit_labels of one view from the truth (gt_corners2d, gt_readable) of suit_images."""
    if "gt_corners2d" not in images or "gt_readable" not in images:
        raise OracleError("the truth stand-in needs studio takes (gt_corners2d, gt_readable); use the 2D chain on "
                          "real images")
    views = [str(v) for v in images["view"].values]
    xs, ys = [], []
    for view in views:
        truth = images["gt_corners2d"].sel(view=view).transpose("frame", "corner", "uv").values.astype(np.float64)
        readable = images["gt_readable"].sel(view=view).transpose("frame", "corner").values
        rng = np.random.default_rng([config.seed, int(images["frame"].values[0]), sum(map(ord, view))])
        labels = noisy_labels(truth, readable, config, rng)
        xs.append(labels[..., 0])
        ys.append(labels[..., 1])
    x, y = np.stack(xs).astype(np.float32), np.stack(ys).astype(np.float32)
    return xr.Dataset({"x": (("view", "frame", "corner"), x), "y": (("view", "frame", "corner"), y),
                       "quads": (("view", "frame", "corner"), np.isfinite(x).astype(np.int8))},
                      coords={"view": np.array(views, dtype=object), "frame": images["frame"].values,
                              "corner": images["corner"].values})

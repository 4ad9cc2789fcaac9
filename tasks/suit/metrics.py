"""Scoring the suit system against the studio's truth (Chen et al. 2021, §6: corner detection and labelling
rates, localisation error, the networks' accuracies, reprojection errors; 3D error of observed and filled corners).

Kernels return sums and error samples so that figures pool over views, frames and takes before they are
averaged. A labelled corner is right when the truth sees that corner within ``match_px`` of the label's pixel.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree


@dataclass(frozen=True)
class LabelCounts:
    readable: int  # true corners readable in the images
    readable_found: int  # of those, labelled right
    visible: int  # true corners visible
    visible_found: int
    labelled: int  # labels given
    wrong: int  # labels that name a corner the truth does not show there
    loc_error_px: np.ndarray  # (right labels,) distance to the true pixel
    loc_error_all_px: np.ndarray  # (labels of visible corners,) the same for every label naming a visible corner


def label_counts(xy: np.ndarray, truth: np.ndarray, visible: np.ndarray, readable: np.ndarray,
                 match_px: float = 2.0) -> LabelCounts:
    """xy (..., corner, 2) labelled pixels, NaN where not labelled; truth (..., corner, 2) true pixels; visible,
    readable (..., corner) bool."""
    labelled = np.isfinite(xy).all(axis=-1)
    err = np.linalg.norm(np.where(labelled[..., None], xy, 0.0) - truth, axis=-1)
    right = labelled & visible & (err <= match_px)
    return LabelCounts(int(readable.sum()), int((right & readable).sum()), int(visible.sum()), int(right.sum()),
                       int(labelled.sum()), int((labelled & ~right).sum()), err[right], err[labelled & visible])


def wrong_labels(xy: np.ndarray, truth: np.ndarray, visible: np.ndarray, match_px: float = 2.0) -> np.ndarray:
    """Labels that name a corner the truth does not show within ``match_px`` of them.  As ``label_counts``'s
    inputs -> (..., corner) bool"""
    labelled = np.isfinite(xy).all(axis=-1)
    err = np.linalg.norm(np.where(labelled[..., None], xy, 0.0) - truth, axis=-1)
    return labelled & ~(visible & (err <= match_px))


@dataclass(frozen=True)
class DetectionCounts:
    visible: int  # true visible corners
    found: int  # of those, with a detection within match_px
    detections: int
    false: int  # detections with no visible true corner within false_px


def detection_counts(xy: np.ndarray, truth: np.ndarray, visible: np.ndarray, match_px: float = 1.5,
                     false_px: float = 3.0) -> DetectionCounts:
    """One image: detections xy (n, 2) (NaN rows ignored), true pixels truth (corner, 2), visible (corner,)."""
    xy = xy[np.isfinite(xy).all(axis=1)]
    seen = truth[visible]
    if not len(seen) or not len(xy):
        return DetectionCounts(len(seen), 0, len(xy), len(xy))
    d_truth, _ = cKDTree(xy).query(seen)
    d_det, _ = cKDTree(seen).query(xy)
    return DetectionCounts(len(seen), int((d_truth <= match_px).sum()), len(xy), int((d_det > false_px).sum()))


def quad_truth(xy: np.ndarray, quads: np.ndarray, truth: np.ndarray, visible: np.ndarray, square_corners: np.ndarray,
               match_px: float = 2.0) -> tuple[np.ndarray, np.ndarray]:
    """Which coded square each candidate quad truly is, and in which rotation.

    xy (n, 2) detections; quads (q, 4) detection indices (-1 padding); truth (corner, 2), visible (corner,);
    square_corners (square, 4). -> square (q,) (-1: not a coded square's four corners), rotation (q,): quad vertex i
    is the square's vertex (i + r) mod 4 (tasks/suit/codes.py), -1 where square is -1.
    """
    square = np.full(len(quads), -1)
    rotation = np.full(len(quads), -1)
    seen = np.flatnonzero(visible & np.isfinite(truth).all(axis=1))
    if not len(seen) or not len(quads):
        return square, rotation
    d, nearest = cKDTree(truth[seen]).query(np.nan_to_num(xy, nan=-1e9))
    corner_of = np.where(d <= match_px, seen[nearest], -1)  # (n,) the true corner at each detection
    ids = np.where(quads >= 0, corner_of[np.maximum(quads, 0)], -1)  # (q, 4)
    lookup = {tuple(np.roll(row, -r)): (s, r) for s, row in enumerate(square_corners) for r in range(4)}
    for q, row in enumerate(ids):
        hit = lookup.get(tuple(row)) if (row >= 0).all() else None
        if hit is not None:
            square[q], rotation[q] = hit
    return square, rotation


def errors_mm(points: np.ndarray, truth: np.ndarray, where: np.ndarray | None = None) -> np.ndarray:
    """Distances (mm) of finite points to their truth: points, truth (..., 3); where (...) bool selects."""
    ok = np.isfinite(points).all(axis=-1)
    if where is not None:
        ok &= where
    return 1000 * np.linalg.norm(points[ok] - truth[ok], axis=-1)


def summary(values: np.ndarray) -> dict:
    """median, mean, p95, p99 and count of a sample (NaN figures when it is empty)."""
    values = np.asarray(values, float)
    if not len(values):
        return {"median": float("nan"), "mean": float("nan"), "p95": float("nan"), "p99": float("nan"), "n": 0}
    p50, p95, p99 = np.percentile(values, [50, 95, 99])
    return {"median": float(p50), "mean": float(values.mean()), "p95": float(p95), "p99": float(p99),
            "n": int(len(values))}

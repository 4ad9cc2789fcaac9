"""The error of 3D markers against their true positions, as pure functions of arrays: per marker-frame distances,
the tail of the error (p95, p99, the share of gross errors) and the worst markers. Any system whose markers have a
truth uses them (DeepMoCap's reflectors, the report's worst-markers table)."""

from __future__ import annotations

import numpy as np

def marker_errors(xyz: np.ndarray, gt: np.ndarray) -> np.ndarray:
    """Distances in mm, NaN where no estimate.  (frame, reflector, 3) m x2 -> (frame, reflector)"""
    return 1000.0 * np.linalg.norm(xyz.astype(np.float64) - gt.astype(np.float64), axis=-1)


GROSS_MM = 100.0  # a marker this far from the truth is a gross error


def tail(values: np.ndarray, gross_mm: float = GROSS_MM) -> dict:
    """The tail of the marker errors written as data: p95 and p99 (mm, linear interpolation between order
    statistics) and the share of them farther than ``gross_mm`` from the truth.  (n,) finite mm -> dict"""
    if not values.size:
        return {"p95_mm": float("nan"), "p99_mm": float("nan"), "gross_share": float("nan")}
    return {"p95_mm": float(np.percentile(values, 95)), "p99_mm": float(np.percentile(values, 99)),
            "gross_share": float(np.mean(values > gross_mm))}


def marker_tails(errors: np.ndarray, gross_mm: float = GROSS_MM) -> dict[str, np.ndarray]:
    """Per marker over time: the largest error (mm) and its frame (-1 where never seen), p95 (mm, linear
    interpolation as ``tail``), the frames farther than ``gross_mm`` and their share of the frames with a value.
    (frame, marker) mm, NaN where no estimate -> each (marker,)"""
    seen = np.isfinite(errors)
    counted = seen.sum(axis=0)
    filled = np.where(seen, errors, -np.inf)
    with np.errstate(invalid="ignore"):
        gross = (np.where(seen, errors, 0.0) > gross_mm).sum(axis=0)
        return {"max_mm": np.where(counted > 0, filled.max(axis=0), np.nan),
                "max_frame": np.where(counted > 0, filled.argmax(axis=0), -1),
                "p95_mm": np.array([np.percentile(errors[seen[:, m], m], 95) if counted[m] else np.nan
                                    for m in range(errors.shape[1])]),
                "gross_frames": gross, "gross_share": np.where(counted > 0, gross / np.maximum(counted, 1), np.nan)}


def worst_markers(errors: np.ndarray, k: int = 5, gross_mm: float = GROSS_MM) -> np.ndarray:
    """Indices of the ``k`` markers worst by p95, ties by the largest error, worst first; markers never seen
    last.  (frame, marker) mm -> (min(k, marker),) int"""
    t = marker_tails(errors, gross_mm)
    order = np.lexsort((-np.nan_to_num(t["max_mm"], nan=-np.inf), -np.nan_to_num(t["p95_mm"], nan=-np.inf)))
    return order[:k]

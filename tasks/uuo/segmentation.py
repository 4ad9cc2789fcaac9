"""Stage 1 of UUO's marker-part matching: rigid segmentation of the markers (Milef et al. 2024, §3.4.1).

Markers on one bone keep their distances; markers on different bones do not. For every pair of trajectories
the spread (standard deviation over time) of their Euclidean distance fills an affinity matrix, and
agglomerative clustering with average linkage cuts it at 5 mm: each group is presumed to ride one bone, and
the number of groups is the length of the kinematic chain the next stage searches for. A pair seen together
in too few frames (a fragment beside another, a ghost) has no measured spread and counts as apart.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import xarray as xr


class SegmentationError(ValueError):
    """Settings or markers rigid segmentation cannot use."""


@dataclass(frozen=True)
class SegmentConfig:
    threshold_mm: float = 5.0  # §3.4.1: the clustering's distance threshold on the spread
    min_common_frames: int = 10  # pairs seen together in fewer frames are not known to be rigid
    apart_mm: float = 1000.0  # the spread given to such pairs (any value far above the threshold)

    def __post_init__(self):
        if not 0 < self.threshold_mm < self.apart_mm or self.min_common_frames < 2:
            raise SegmentationError(f"need 0 < threshold_mm ({self.threshold_mm}) < apart_mm ({self.apart_mm}) and "
                                    f"min_common_frames >= 2 (got {self.min_common_frames})")


def distance_spread(positions: np.ndarray, min_common_frames: int, apart: float) -> np.ndarray:
    """Standard deviation over time of every pair's distance; ``apart`` where a pair shares too few frames.

    positions (frame, marker, 3), NaN where missing -> (marker, marker), 0 on the diagonal  # §3.4.1, Fig. 3
    """
    n = positions.shape[1]
    seen = np.isfinite(positions).all(axis=2)  # (frame, marker)
    out = np.full((n, n), apart)
    np.fill_diagonal(out, 0.0)
    for i in range(n - 1):
        d = np.linalg.norm(positions[:, i + 1:] - positions[:, i:i + 1], axis=2)  # (frame, n - i - 1)
        both = seen[:, i + 1:] & seen[:, i:i + 1]
        count = both.sum(axis=0)
        d = np.where(both, d, 0.0)
        mean = d.sum(axis=0) / np.maximum(count, 1)
        var = (np.where(both, d - mean, 0.0) ** 2).sum(axis=0) / np.maximum(count - 1, 1)
        spread = np.where(count >= min_common_frames, np.sqrt(var), apart)
        out[i, i + 1:] = out[i + 1:, i] = spread
    return out


def segment(positions: np.ndarray, config: SegmentConfig) -> np.ndarray:
    """Group index of every trajectory (groups numbered by size, largest first).  (frame, marker, 3) -> (marker,)"""
    from sklearn.cluster import AgglomerativeClustering

    n = positions.shape[1]
    if n < 2:
        return np.zeros(n, np.int64)
    spread_mm = 1000.0 * distance_spread(positions, config.min_common_frames, config.apart_mm / 1000.0)
    labels = AgglomerativeClustering(n_clusters=None, metric="precomputed", linkage="average",
                                     distance_threshold=config.threshold_mm).fit_predict(spread_mm)
    sizes = np.bincount(labels)
    rank = np.empty_like(sizes)
    rank[np.lexsort((np.arange(len(sizes)), -sizes))] = np.arange(len(sizes))  # largest first, ties by first seen
    return rank[labels].astype(np.int64)


def rigid_segments(markers: xr.Dataset, config: SegmentConfig) -> xr.Dataset:
    """Stage ``rigid_segments``: each trajectory's rigid group, from a raw_markers take."""
    positions = markers["position"].transpose("frame", "marker", "xyz").values.astype(np.float64)
    groups = segment(positions, config)
    return xr.Dataset({"segment": (("marker",), groups)}, coords={"marker": markers["marker"].values},
                      attrs={"segments": int(groups.max(initial=-1) + 1)})

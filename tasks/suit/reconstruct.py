"""Labelled corners to 3D points, frame by frame, with the paper's outlier filter (§3.3 "Corner labeling and 3D
Reconstruction" and "Error Filtering", Chen et al. 2021).

Each view claims a 2D position (distorted pixels) for some of the suit's uniquely labelled corners; a view that misread
a code claims a corner it does not see. Per corner, with ``C`` the views that claim it:

1. ``|C| >= 3``: triangulate the corner from every pair of views in ``C`` (Linear-LS) and take the pair point with the
   least reprojection error averaged over all of ``C`` as the consensus point (§3.3);
2. measure the consensus point's reprojection error in each view of ``C`` and drop the views above
   ``Q3 + 1.5 IQR`` of those errors (the 1.5 x interquartile range rule, §3.3);
3. re-solve from the views kept: Linear-LS, then the nonlinear least squares of the reprojection error (§3.3);
4. discard the corner when its mean reprojection error over the views kept exceeds 1.5 px (§3.3; the only check of a
   corner claimed by two views) or fewer than two views are kept.

Two additions, not in the paper, make step 1-2 hold when wrong claims are not a small minority:

- ``max_view_error_px``: a view whose error from the consensus point exceeds it is dropped too. The IQR rule alone
  misses outliers when they are many (3 wrong views of 8 put Q3 among them), and it can never drop a view of a
  corner claimed by three (two of the three errors are those of the pair itself, about zero, and Q3 + 1.5 IQR then
  lies above the third): the wrong views are kept and the corner is lost to the 1.5 px rule;
- ``selection_cap_px``: in step 1 each view's error counts at most this much (a point behind a claiming camera counts
  as the cap). With the plain mean, a few claims 100 px off outweigh the small errors of the right views, and a pair
  built with a wrong view can win (a corner claimed by three views, one of them wrong, is then lost about two times
  in three); the cap bounds each view's say. ``math.inf`` gives the paper's plain mean.

Errors in step 1 are measured in undistorted pixels (pinhole projection of every pair point into every claimant, all
at once); steps 2-4 use the full camera model. ``tasks.shared.triangulation`` holds the generic solves.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np
import xarray as xr

from mocapflow.tasks.shared.calibration_error import perturbed
from mocapflow.tasks.shared.cameras import Camera, camera_of
from mocapflow.tasks.shared.triangulation import (
    TriangulationError,
    check_cameras,
    linear_rows,
    projection_matrices,
    refine_points,
    reprojection_errors,
    solve_linear,
    triangulate_linear,
    undistort_pixels,
)


class ReconstructError(ValueError):
    """Corner observations or cameras that cannot be reconstructed (shapes, view counts, missing calibration)."""


@dataclass(frozen=True)
class ReconstructConfig:
    """The outlier filter's thresholds (pixels): see the module's docstring."""

    max_mean_error_px: float = 1.5  # §3.3, Chen et al. 2021: discard corners above 1.5 px average reprojection error
    iqr_factor: float = 1.5  # §3.3, Chen et al. 2021: the 1.5 x interquartile range rule
    max_view_error_px: float = 3.0  # not in the paper: drop a view this far from the consensus point
    min_views: int = 2  # views a corner must keep
    selection_cap_px: float = 10.0  # not in the paper: most that one view's error counts when choosing the pair
    # Studio takes carry their exact cameras; this triangulates with cameras off by a real calibration's error
    # instead (tasks/shared/calibration_error.py: this RMS in px over the volume, 0.2-0.3 px in practice).
    calibration_error_px: float = 0.0
    calibration_seed: int = 0
    # views among those a corner keeps whose label was read from a square (suit_labels ``quads`` > 0) that it needs:
    # labels grown over the grid (tasks/suit/grow.py, ``quads`` 0) add views to corners but make none alone. On the
    # training takes, 0 triangulated 16 % more corners and put 13 of 15,138 over 5 mm off; 2 (as min_views) none
    # more than the labels read put there (1 of 13,046)
    read_views: int = 2
    grown_px: float = 1.0  # a grown label joins its corner's views only this close to the read views' point

    def __post_init__(self):
        if self.read_views < 0 or self.grown_px <= 0:
            raise ReconstructError(f"read_views must be >= 0 (0: every label counts alike) and grown_px > 0, got "
                                   f"{self.read_views} and {self.grown_px}")
        if self.min_views < 2:
            raise ReconstructError(f"min_views must be at least 2 (a point needs two views), got {self.min_views}")
        if not 0 <= self.calibration_error_px <= 20:
            raise ReconstructError(f"calibration_error_px must be 0-20 px RMS (a real calibration leaves 0.2-0.3), "
                                   f"got {self.calibration_error_px}")


@dataclass(frozen=True)
class Reconstruction:
    """Corners in 3D and how each view's claim fared; a leading frame axis on each array for several frames.

    ``position`` (corner, 3) world metres, NaN where not reconstructed; ``kept`` (view, corner) the views the point was
    solved from (all False for a corner not reconstructed); ``error_px`` (view, corner) the reprojection error of the
    solved point in every view that claims the corner, kept or not (also for a corner discarded for its error), NaN
    where the view does not claim it or no point was solved (fewer than two views kept), inf where the point lies
    behind that view's camera."""

    position: np.ndarray
    kept: np.ndarray
    error_px: np.ndarray


def reconstruct_frames(xy: np.ndarray, cameras: Sequence[Camera], config: ReconstructConfig = ReconstructConfig()
                       ) -> Reconstruction:
    """:func:`reconstruct_frame` of each frame.  (frame, view, corner, 2) -> (frame, corner, 3), (frame, view, corner)
    x 2"""
    xy = _checked(xy, cameras, "(frame, view, corner, 2)")
    frames = [_reconstruct(one, cameras, config) for one in xy]
    if not frames:
        views, corners = xy.shape[1:3]
        return Reconstruction(np.zeros((0, corners, 3)), np.zeros((0, views, corners), dtype=bool),
                              np.zeros((0, views, corners)))
    return Reconstruction(*(np.stack(parts) for parts in zip(*((f.position, f.kept, f.error_px) for f in frames))))


def reconstruct_frame(xy: np.ndarray, cameras: Sequence[Camera], config: ReconstructConfig = ReconstructConfig()
                      ) -> Reconstruction:
    """3D corners of one frame from each view's claimed pixels (NaN where a view claims nothing), the outlier views
    dropped (§3.3, Chen et al. 2021).  (view, corner, 2), cameras in view order -> (corner, 3), (view, corner) x 2"""
    return _reconstruct(_checked(xy, cameras, "(view, corner, 2)"), cameras, config)


def _reconstruct(xy: np.ndarray, cameras: Sequence[Camera], config: ReconstructConfig) -> Reconstruction:
    claims = np.isfinite(xy).all(axis=-1)  # (view, corner)
    undistorted = undistort_pixels(xy, cameras)  # (view, corner, 2)
    P = projection_matrices(cameras)  # (view, 3, 4)
    consensus = _consensus_points(undistorted, P, claims, config.selection_cap_px)  # (corner, 3)
    kept = claims & ~_outlier_views(reprojection_errors(consensus, xy, cameras), claims, config)
    kept &= kept.sum(axis=0) >= 2
    points = refine_points(triangulate_linear(undistorted, P, kept), xy, cameras, kept)  # §3.3: Linear-LS, then NLS
    errors = reprojection_errors(points, xy, cameras)  # (view, corner)
    errors[:, kept.sum(axis=0) < 2] = np.nan
    mean = np.where(kept, errors, 0.0).sum(axis=0) / np.maximum(kept.sum(axis=0), 1)  # (corner,)
    good = (kept.sum(axis=0) >= config.min_views) & (mean <= config.max_mean_error_px)  # §3.3: 1.5 px rule
    return Reconstruction(np.where(good[:, None], points, np.nan), kept & good, errors)


def _consensus_points(undistorted: np.ndarray, P: np.ndarray, claims: np.ndarray, cap: float) -> np.ndarray:
    """Per corner claimed by three views or more, the pair point with the least mean (capped) reprojection error over
    its claimants (§3.3, Chen et al. 2021); NaN for other corners.  (view, corner, 2), (view, 3, 4), (view, corner)
    -> (corner, 3)"""
    first, second = np.triu_indices(claims.shape[0], 1)  # (pair,)
    count = claims.sum(axis=0)  # (corner,)
    both = claims[first] & claims[second] & (count >= 3)  # (pair, corner)
    pair, corner = np.nonzero(both)  # (candidate,)
    rows = linear_rows(undistorted, P)  # (view, corner, 2, 4)
    candidates = solve_linear(np.concatenate([rows[first[pair], corner], rows[second[pair], corner]], axis=1))
    score = np.full(both.shape, np.inf)  # (pair, corner)
    score[pair, corner] = _mean_capped_error(candidates, undistorted, P, claims, corner, cap)
    index = np.zeros(both.shape, dtype=np.intp)  # (pair, corner) -> candidate
    index[pair, corner] = np.arange(len(pair))
    consensus = np.full((claims.shape[1], 3), np.nan)
    chosen = np.flatnonzero(count >= 3)
    consensus[chosen] = candidates[index[np.argmin(score[:, chosen], axis=0), chosen]]
    return consensus


def _mean_capped_error(points: np.ndarray, undistorted: np.ndarray, P: np.ndarray, claims: np.ndarray,
                       corner: np.ndarray, cap: float) -> np.ndarray:
    """Mean over the views claiming ``corner`` of each point's pinhole reprojection error in undistorted pixels, each
    view's error at most ``cap`` (a point behind the camera or not finite counts as ``cap``).  (n, 3),
    (view, corner, 2), (view, 3, 4), (view, corner), (n,) -> (n,)"""
    image = np.matmul(P[:, :, :3], points.T) + P[:, :, 3:]  # (view, 3, n)
    depth = image[:, 2]  # (view, n)
    seen = undistorted.transpose(2, 0, 1)[:, :, corner]  # (2, view, n)
    with np.errstate(divide="ignore", invalid="ignore"):
        dx, dy = image[:, 0] / depth - seen[0], image[:, 1] / depth - seen[1]
        error = np.where(depth > 0, np.fmin(np.sqrt(dx * dx + dy * dy), cap), cap)  # (view, n); NaN -> cap
    weight = claims.astype(np.float64)[:, corner]  # (view, n)
    return np.einsum("vn,vn->n", error, weight) / weight.sum(axis=0)


def _outlier_views(errors: np.ndarray, claims: np.ndarray, config: ReconstructConfig) -> np.ndarray:
    """Claims of corners with three claimants or more whose error from the consensus point is above Q3 + 1.5 IQR of
    the corner's errors (§3.3, Chen et al. 2021) or above ``max_view_error_px`` (not in the paper).
    (view, corner) x 2 -> (view, corner)"""
    q1, q3 = _quartiles(errors, claims)  # (corner,) each
    high = (errors > q3 + config.iqr_factor * (q3 - q1)) | (errors > config.max_view_error_px)  # NaN compares False
    return claims & high & (claims.sum(axis=0) >= 3)


def _quartiles(errors: np.ndarray, claims: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """First and third quartile (linear interpolation, as ``np.percentile``) of each corner's errors over its claiming
    views, inf counted as a huge finite error (1e12 px); NaN for a corner nobody claims.
    (view, corner) x 2 -> (corner,) x 2"""
    count = claims.sum(axis=0)  # (corner,)
    ordered = np.sort(np.where(claims, np.fmin(errors, 1e12), 1e13), axis=0)  # claims first, ascending
    quartiles = []
    for q in (0.25, 0.75):
        at = q * np.maximum(count - 1, 0)  # (corner,)
        low = np.floor(at).astype(int)
        high = np.minimum(low + 1, np.maximum(count - 1, 0))
        below, above = np.take_along_axis(ordered, low[None], 0)[0], np.take_along_axis(ordered, high[None], 0)[0]
        quartiles.append(np.where(count > 0, below + (at - low) * (above - below), np.nan))
    return quartiles[0], quartiles[1]


def _checked(xy: np.ndarray, cameras: Sequence[Camera], shape: str) -> np.ndarray:
    """``xy`` as float with the dims of ``shape`` and one calibrated camera per view; ReconstructError otherwise."""
    xy = np.asarray(xy, dtype=np.float64)
    dims = shape.count(",") + 1
    if xy.ndim != dims or xy.shape[-1] != 2:
        raise ReconstructError(f"xy must be corner pixels of shape {shape} with NaN where a view claims nothing, "
                               f"got shape {xy.shape}")
    try:
        check_cameras(cameras, xy.shape[-3])
    except TriangulationError as exc:
        raise ReconstructError(str(exc)) from exc
    return xy


def reconstruct_read_first(xy: np.ndarray, read: np.ndarray, cameras: Sequence[Camera],
                           config: ReconstructConfig = ReconstructConfig()) -> Reconstruction:
    """Corners solved from the claims read from squares, then again with the grown claims that agree with them.

    xy (frame, view, corner, 2), read (frame, view, corner) bool. The read claims make the corners (at least
    ``read_views`` of them kept); a grown claim within ``grown_px`` of its corner's reprojection joins the views
    the first solve kept (those it dropped stay out) and the corner is solved again from them (the outlier rule
    still applies)."""
    first = reconstruct_frames(np.where(read[..., None], xy, np.nan), cameras, config)
    grown = np.isfinite(xy).all(axis=-1) & ~read
    if not grown.any():
        drop_unread(first, read, config.read_views)
        return first
    join = np.zeros_like(grown)
    for f in np.flatnonzero(grown.any(axis=(1, 2))):
        with np.errstate(invalid="ignore"):
            join[f] = grown[f] & (reprojection_errors(first.position[f], xy[f], cameras) <= config.grown_px)
    out = reconstruct_frames(np.where((first.kept | join)[..., None], xy, np.nan), cameras, config)
    drop_unread(out, read, config.read_views)
    return out


def drop_unread(out, read: np.ndarray, need: int) -> None:
    """Un-triangulate (in place) the corners of ``out`` (reconstruct_frames' result) that keep fewer than ``need``
    views whose label was read from a square (``read`` (frame, view, corner) bool)."""
    alone = (out.kept & read).sum(axis=1) < need  # (frame, corner)
    out.position[alone] = np.nan
    out.kept[np.broadcast_to(alone[:, None, :], out.kept.shape)] = False


def triangulate_corners(labels: xr.Dataset, images: xr.Dataset, config: ReconstructConfig) -> xr.Dataset:
    """Task: the labelled corners of every view (suit_labels) -> triangulated corners (suit_points), the cameras
    from the images' calibration (perturbed by ``calibration_error_px`` when it is set)."""
    views = [str(v) for v in labels["view"].values]
    cameras = [camera_of(images, v) for v in views]
    if config.calibration_error_px > 0:
        rng = np.random.default_rng([config.calibration_seed, 29])
        cameras = list(perturbed(cameras, config.calibration_error_px, rng))
    xy = np.stack([labels["x"].transpose("frame", "view", "corner").values,
                   labels["y"].transpose("frame", "view", "corner").values], axis=-1).astype(np.float64)
    if config.read_views:  # labels read from squares name each corner with its quads; grown ones with none
        read = labels["quads"].transpose("frame", "view", "corner").values > 0
        out = reconstruct_read_first(xy, read, cameras, config)
    else:
        out = reconstruct_frames(xy, cameras, config)  # (frame, corner, 3), (frame, view, corner) x 2
    return xr.Dataset(
        {"position": (("frame", "corner", "xyz"), out.position.astype(np.float32)),
         "kept": (("frame", "view", "corner"), out.kept),
         "error": (("frame", "view", "corner"), out.error_px.astype(np.float32))},
        coords={"frame": labels["frame"].values, "corner": labels["corner"].values,
                "view": np.array(views, dtype=object), "xyz": np.array(["x", "y", "z"], dtype=object)},
        attrs={"length_unit": "m", "up_axis": "Z", "fps": float(images.attrs["fps"])})

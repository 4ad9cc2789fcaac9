"""Keypoints of several calibrated views triangulated with Pose2Sim's outlier rule, then read as template joints.

Pose2Sim (Pagnon, Domalain & Reveret 2022, "Pose2Sim: an open-source Python package for multiview markerless
kinematics", JOSS 7(77) 4362; its ``triangulation.py``) triangulates each keypoint of each frame from every camera
whose 2D likelihood passes a threshold (``likelihood_threshold_triangulation``, 0.3), weighting each camera's DLT
rows by that likelihood; while the reprojection error exceeds ``reproj_error_threshold_triangulation`` and enough
cameras remain it leaves cameras out, and a keypoint whose error stays above the threshold is not given (later
interpolated over short gaps). Here, per keypoint and frame, all at once (:func:`triangulate_views`):

1. the views whose confidence is at least ``min_confidence`` observe it;
2. it is triangulated from them by the house's Linear-LS (tasks/shared/triangulation.py, Hartley & Sturm 1997),
   each view's two rows scaled by its confidence;
3. its reprojection error is measured in every view used (distorted pixels, the full camera model); while the
   largest exceeds ``threshold_px`` and at least ``min_views`` views would remain, that view is dropped and the
   point triangulated again from the rest (``search: worst``, the default: one view per round, the worst first);
4. a point still above the threshold is given as NaN when ``discard`` is set (Pose2Sim's rule), else kept.

``search: subsets`` is Pose2Sim's own search instead: while the least mean reprojection error exceeds the
threshold, the point is triangulated from every subset of its views one view smaller, then two, ... (at least
``min_views`` left), and the subset of least mean error kept (with four views 1 + 4 + 6 solves at most). On
planted outliers it is the exact one: with one view of four planted 60 px off, the greedy rule drops a right view
for 15 of 200 points (a wrong view pulls the point so that a right one shows the largest error), the subset search
never (tests/tasks/markerless/test_triangulate.py). On BlazePose's keypoints it does worse: a two-view subset of
nearly opposite cameras fits a wrong point with a small error. One studio walk, five cameras, ten frames at
threshold 15 px: greedy 58.6 mm MPJPE (86 % of joints given), subsets 65.4 mm (92 %); docs/markerless.md.

BlazePose sometimes takes a body's back for its front and gives a view's landmarks left for right (a third of the
frames of a camera facing the subject's back, on the studio's takes). With ``swaps`` (Pose2Sim's
``handle_LR_swap``, done per view and frame rather than per keypoint) each view is checked against the others
first (:func:`swapped_views`): the landmarks triangulated without it are projected into it, and where its
landmarks read mirrored (MIRRORED: left and right exchanged) lie nearer those projections (median over its sided
landmarks) than as given by at least ``swap_ratio`` (a side view reads about as well either way), the view's
frame is read mirrored before the triangulation above.

With ``refine`` the kept points are then moved to the least squared reprojection error over their kept views
(refine_points: the full camera model, unweighted), which Pose2Sim does not do.

The 33 landmarks are then read as the template's 20 joints (tasks/markerless/joints.py).
"""

from __future__ import annotations

import dataclasses
import itertools
from dataclasses import dataclass
from typing import NamedTuple, Sequence

import numpy as np
import xarray as xr

from mocapflow.tasks.shared.body import JOINT_NAMES
from mocapflow.tasks.shared.cameras import Camera, camera_of
from mocapflow.tasks.shared.triangulation import (claimed, linear_rows, projection_matrices, refine_points,
                                                  reprojection_errors, solve_linear, undistort_pixels)
from mocapflow.tasks.markerless.blazepose import MIRRORED
from mocapflow.tasks.markerless.joints import template_joints


@dataclass(frozen=True)
class TriangulateConfig:
    """Pose2Sim's outlier rule: views below ``min_confidence`` unused; while the reprojection error exceeds
    ``threshold_px`` and ``min_views`` would remain, views left out (``search``: the worst view, or the best subset
    one view smaller); ``discard``: a point still above it not given. ``refine``: the kept points refined by
    Levenberg-Marquardt over their views (not Pose2Sim's)."""

    min_confidence: float = 0.3  # Pose2Sim's likelihood_threshold_triangulation
    threshold_px: float = 15.0  # Pose2Sim's reproj_error_threshold_triangulation is 15 px on its 1080p demo
    min_views: int = 2
    discard: bool = True
    refine: bool = False
    search: str = "worst"  # drop the worst view while above; "subsets": Pose2Sim's search over smaller subsets
    swaps: bool = True  # a view's frame read with left and right exchanged where the other views say so
    swap_ratio: float = 0.5  # ... where its landmarks read mirrored lie this much nearer the others' (median)

    def __post_init__(self):
        if self.search not in ("subsets", "worst"):
            raise ValueError(f"search must be 'subsets' (Pose2Sim's) or 'worst', got {self.search!r}")
        if not (0 <= self.min_confidence < 1 and self.threshold_px > 0 and self.min_views >= 2):
            raise ValueError(f"triangulation settings out of range: min_confidence in [0, 1) (got "
                             f"{self.min_confidence}), threshold_px > 0 (got {self.threshold_px}), min_views >= 2 "
                             f"(got {self.min_views})")


class Triangulated(NamedTuple):
    points: np.ndarray  # (point, 3) m, NaN where not given
    kept: np.ndarray  # (view, point) bool, the views the point was triangulated from
    error_px: np.ndarray  # (view, point) reprojection error in every observing view, NaN where it does not observe
    dropped: np.ndarray  # (view, point) bool, the views the rule dropped


def weighted_linear(xy_undistorted: np.ndarray, P: np.ndarray, use: np.ndarray, weight: np.ndarray) -> np.ndarray:
    """Linear-LS points from the views of ``use``, each view's rows scaled by ``weight``; NaN where fewer than two
    views are used.  (view, point, 2), (view, 3, 4), (view, point) bool, (view, point) -> (point, 3)"""
    safe = np.where(use[..., None], xy_undistorted, 0.0)
    rows = linear_rows(safe, P) * np.where(use, weight, 0.0)[..., None, None]  # (view, point, 2, 4)
    rows = np.where(np.isfinite(rows), rows, 0.0)
    stacked = rows.transpose(1, 0, 2, 3).reshape(use.shape[1], -1, 4)
    points = solve_linear(stacked)
    points[use.sum(axis=0) < 2] = np.nan
    return points


def triangulate_views(xy: np.ndarray, confidence: np.ndarray, cameras: Sequence[Camera],
                      config: TriangulateConfig = TriangulateConfig()) -> Triangulated:
    """Points seen in several views, by Pose2Sim's outlier rule (module docstring).  xy (view, point, 2) distorted
    pixels (NaN where not seen), confidence (view, point) -> Triangulated."""
    xy = np.asarray(xy, np.float64)
    confidence = np.nan_to_num(np.asarray(confidence, np.float64))
    observed = claimed(xy) & (confidence >= config.min_confidence) & (confidence > 0)
    und, P = undistort_pixels(xy, cameras), projection_matrices(cameras)
    # a view's weight: its confidence, floored so that a used view never vanishes from the system
    weight = np.maximum(confidence, 1e-3)

    def solve(use: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        points = weighted_linear(und, P, use, weight)
        return points, reprojection_errors(points, np.where(use[..., None], xy, np.nan), cameras)  # NaN: unused

    if config.search == "worst":
        use, points, error = observed.copy(), *solve(observed)
        while True:
            score = np.where(use, np.nan_to_num(error, nan=-1.0), -1.0)
            worst, largest = score.argmax(axis=0), score.max(axis=0)
            drop = (largest > config.threshold_px) & (use.sum(axis=0) > config.min_views)
            if not drop.any():
                break
            use[worst[drop], np.flatnonzero(drop)] = False
            points, error = solve(use)
        criterion = np.where(use, error, -np.inf).max(axis=0)
    else:
        use, points, criterion = subsets(observed, solve, config)
    if config.refine:
        points = refine_points(points, xy, cameras, mask=use)
    final = reprojection_errors(points, np.where(observed[..., None], xy, np.nan), cameras)
    lost = use.sum(axis=0) < config.min_views
    if config.discard:
        lost |= ~(criterion <= config.threshold_px)
    points[lost] = np.nan
    return Triangulated(points, use & ~lost[None], final, observed & ~use)


def mean_error(error: np.ndarray, use: np.ndarray) -> np.ndarray:
    """Each point's mean reprojection error over the views of ``use``; inf where fewer than two.
    (view, point), (view, point) -> (point,)"""
    n = use.sum(axis=0)
    total = np.where(use, error, 0.0).sum(axis=0)
    return np.where(n >= 2, total / np.maximum(n, 1), np.inf)


def subsets(observed: np.ndarray, solve, config: TriangulateConfig) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Pose2Sim's search: each point from all its views, then, while its least mean reprojection error exceeds the
    threshold, from every subset with one view fewer (down to ``min_views``), the subset of least mean error kept.
    -> (use (view, point), points (point, 3), their mean error (point,))"""
    n_view, n_point = observed.shape
    use = observed.copy()
    points, error = solve(use)
    best = mean_error(error, use)
    counts = observed.sum(axis=0)
    for k in range(1, n_view - config.min_views + 1):
        open_ = (best > config.threshold_px) & (counts - k >= config.min_views)
        if not open_.any():
            break
        found = np.full(n_point, np.inf)
        found_use, found_points = use.copy(), points.copy()
        for left_out in itertools.combinations(range(n_view), k):
            out = np.zeros(n_view, bool)
            out[list(left_out)] = True
            apply = open_ & observed[out].all(axis=0)  # the points that see every view left out
            if not apply.any():
                continue
            trial = observed & ~out[:, None] & apply[None]
            trial_points, trial_error = solve(trial)
            mean = mean_error(trial_error, trial)[apply]
            better = np.zeros(n_point, bool)
            better[apply] = mean < found[apply]
            found[better] = mean[better[apply]]
            found_use[:, better], found_points[better] = trial[:, better], trial_points[better]
        # a point takes the best subset of this size; once under the threshold it is settled
        take = open_ & np.isfinite(found)
        use[:, take], points[take], best[take] = found_use[:, take], found_points[take], found[take]
    return use, points, best


def swapped_views(xy: np.ndarray, confidence: np.ndarray, cameras: Sequence[Camera],
                  config: TriangulateConfig) -> np.ndarray:
    """Which views' frames read left for right: each view's landmarks against those triangulated from the other
    views (the same rule), as given and mirrored; mirrored where that is nearer by ``swap_ratio`` (median over the
    sided landmarks both readings give).  xy (view, frame, 33, 2), confidence (view, frame, 33) -> (view, frame) bool"""
    n_view, n_frame, n_landmark = confidence.shape
    sided = MIRRORED != np.arange(n_landmark)
    out = np.zeros((n_view, n_frame), bool)
    if n_view < 3:  # two views cannot outvote each other
        return out
    for v in range(n_view):
        others = confidence.copy()
        others[v] = 0.0
        points = triangulate_views(xy.reshape(n_view, -1, 2), others.reshape(n_view, -1), cameras,
                                   dataclasses.replace(config, swaps=False)).points
        seen = cameras[v].project(points)[0].reshape(n_frame, n_landmark, 2)
        usable = confidence[v] >= config.min_confidence
        given = np.where(usable[..., None], xy[v], np.nan)
        as_given = np.linalg.norm(given - seen, axis=-1)[:, sided]
        mirrored = np.linalg.norm(given[:, MIRRORED] - seen, axis=-1)[:, sided]
        both = np.isfinite(as_given) & np.isfinite(mirrored)
        for f in range(n_frame):
            if both[f].sum() >= 4:
                out[v, f] = np.median(mirrored[f, both[f]]) < config.swap_ratio * np.median(as_given[f, both[f]])
    return out


def triangulate_keypoints(keypoints: xr.Dataset, images: xr.Dataset, config: TriangulateConfig) -> xr.Dataset:
    """Stage ``joints``: every view's 2D keypoints (x, y, confidence) triangulated with the calibration of the
    images, landmark by landmark and frame by frame (Pose2Sim's rule), and read as the template's 20 joints."""
    views = [str(v) for v in keypoints["view"].values]
    cameras = [camera_of(images, v) for v in views]
    dims = ("view", "frame", "landmark")
    xy = np.stack([keypoints["x"].transpose(*dims).values, keypoints["y"].transpose(*dims).values], axis=-1)
    conf = keypoints["confidence"].transpose(*dims).values
    n_view, n_frame, n_landmark = conf.shape
    swapped = swapped_views(xy, conf, cameras, config) if config.swaps else np.zeros((n_view, n_frame), bool)
    xy = np.where(swapped[..., None, None], xy[:, :, MIRRORED], xy)
    conf = np.where(swapped[..., None], conf[:, :, MIRRORED], conf)
    out = triangulate_views(xy.reshape(n_view, -1, 2), conf.reshape(n_view, -1), cameras, config)
    landmarks = out.points.reshape(n_frame, n_landmark, 3)
    kept = out.kept.reshape(n_view, n_frame, n_landmark)
    # a landmark's confidence: the mean of its kept views' (0 where not given)
    landmark_conf = np.where(kept, conf, 0.0).sum(axis=0) / np.maximum(kept.sum(axis=0), 1)
    joints, joint_conf = template_joints(landmarks, landmark_conf)
    return xr.Dataset(
        {"joints": (("frame", "joint", "xyz"), joints.astype(np.float32)),
         "joint_confidence": (("frame", "joint"), joint_conf.astype(np.float32)),
         "landmarks": (("frame", "landmark", "xyz"), landmarks.astype(np.float32)),
         "kept": (("frame", "view", "landmark"), kept.transpose(1, 0, 2)),
         "swapped": (("frame", "view"), swapped.T),
         "dropped": (("frame", "view", "landmark"), out.dropped.reshape(n_view, n_frame, n_landmark).transpose(1, 0, 2)),
         "error": (("frame", "view", "landmark"),
                   out.error_px.reshape(n_view, n_frame, n_landmark).transpose(1, 0, 2).astype(np.float32))},
        coords={"frame": keypoints["frame"].values, "view": np.array(views, dtype=object),
                "landmark": keypoints["landmark"].values, "joint": np.array(JOINT_NAMES, dtype=object),
                "xyz": np.array(["x", "y", "z"], dtype=object)},
        attrs={"length_unit": "m", "up_axis": "Z", "fps": float(images.attrs["fps"]),
               "threshold_px": float(config.threshold_px)})

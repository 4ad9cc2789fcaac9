"""Triangulation of points seen in several calibrated views: a linear solve, then its nonlinear refinement.

Every system that sees the same point in several calibrated :class:`Camera` views can use these, many points at once,
each point from its own subset of views (a ``mask``, view by point):

- :func:`undistort_pixels` turns observed (distorted) pixels into undistorted pixels (``cv2.undistortPoints`` with
  ``P = K``), so that :func:`projection_matrices` ``K [R | t]`` map world points onto them;
- :func:`linear_rows` and :func:`solve_linear` are the linear method of Hartley & Sturm (1997), "Linear-LS": each view
  gives two rows ``x p3 - p1`` and ``y p3 - p2`` of a system ``A X = 0`` in the homogeneous point ``X``, and with
  ``X = (x, y, z, 1)`` it is solved as an ordinary least-squares problem in ``(x, y, z)`` (normal equations, one batched
  3x3 solve for all points); :func:`triangulate_linear` does both for points seen by any subset of views;
- :func:`refine_points` minimises the reprojection error through the full OpenCV camera model (distortion included),
  starting from the linear solution;
- :func:`project_points` and :func:`reprojection_errors` measure the result in every view's (distorted) pixels.

Two choices were measured (CPU time on one core, the frame of ``benchmarks/suit_reconstruct.py``: 1,500 points, each
seen by 3-8 of 12 views):

- the linear solve: Linear-LS by normal equations (a closed-form 3x3 solve per point) takes about 3.5 ms for the
  frame's 21,000 pair systems, where the SVD of the same homogeneous 4x4 systems ("Linear-Eigen") takes about 59 ms;
  either is only the start of the refinement;
- the refinement, kept: a vectorised Levenberg-Marquardt with one damping factor per point and OpenCV's analytic
  Jacobians (``cv2.projectPoints`` gives d pixel / d camera-frame point) takes about 14 ms for the frame, against
  about 44 ms for ``scipy.optimize.least_squares`` (trf) with a block-diagonal ``jac_sparsity`` (3 unknowns per point),
  the two results within 0.001 mm (``benchmarks/suit_reconstruct.py --compare-scipy``).

Linear-LS is not invariant to the choice of world frame: keep the world origin near the captured volume (metres).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import cv2
import numpy as np
from scipy.sparse import csr_matrix

from mocapflow.tasks.shared.cameras import Camera, undistort

_ZERO3 = np.zeros(3)


class TriangulationError(ValueError):
    """Observations, points and cameras that do not fit together (shapes, counts, missing calibration)."""


@dataclass(frozen=True)
class RefineConfig:
    """The per-point Levenberg-Marquardt of :func:`refine_points`: at most ``max_iterations`` steps, stopped once no
    point moves more than ``step_tol_m`` metres; ``damping`` is the starting damping factor of every point."""

    max_iterations: int = 10
    step_tol_m: float = 1e-7
    damping: float = 1e-3


def check_cameras(cameras: Sequence[Camera], views: int, what: str = "xy") -> None:
    """Raise TriangulationError unless there is one calibrated :class:`Camera` for each of ``views`` views."""
    if len(cameras) != views:
        raise TriangulationError(f"{what} has {views} views but {len(cameras)} cameras were given; "
                                 "pass one camera per view, in the views' order")
    for v, cam in enumerate(cameras):
        if not isinstance(cam, Camera):
            raise TriangulationError(f"view {v} has no calibration (its camera is {cam!r}); calibrate the view or "
                                     "drop it from the observations")


def check_observations(xy: np.ndarray, cameras: Sequence[Camera]) -> np.ndarray:
    """``xy`` as float (view, point, 2), checked against ``cameras``; raise TriangulationError naming what is wrong."""
    xy = np.asarray(xy, dtype=np.float64)
    if xy.ndim != 3 or xy.shape[2] != 2:
        raise TriangulationError(f"xy must be pixels of shape (view, point, 2), got shape {xy.shape}")
    check_cameras(cameras, xy.shape[0])
    return xy


def claimed(xy: np.ndarray, mask: np.ndarray | None = None) -> np.ndarray:
    """Which views observe which points: both coordinates finite (and ``mask``, when given).  (view, point, 2) ->
    (view, point)"""
    seen = np.isfinite(xy).all(axis=-1)
    if mask is None:
        return seen
    mask = np.asarray(mask, dtype=bool)
    if mask.shape != seen.shape:
        raise TriangulationError(f"mask must have shape (view, point) = {seen.shape}, got {mask.shape}")
    return seen & mask


def projection_matrices(cameras: Sequence[Camera]) -> np.ndarray:
    """``K [R | t]`` of each camera: world points to undistorted pixels.  -> (view, 3, 4)"""
    return np.stack([cam.K @ cam.world_to_cam[:3] for cam in cameras])


def undistort_pixels(xy: np.ndarray, cameras: Sequence[Camera]) -> np.ndarray:
    """Undistorted pixels of observed pixels (``cv2.undistortPoints`` with ``P = K``); NaN stays NaN.
    (view, point, 2) -> (view, point, 2)"""
    xy = check_observations(xy, cameras)
    out = np.full(xy.shape, np.nan)
    for v, cam in enumerate(cameras):
        seen = np.isfinite(xy[v]).all(axis=1)  # (point,)
        if seen.any():
            norm = undistort(xy[v, seen], cam.K, cam.dist)  # (n, 2) normalized image coordinates
            out[v, seen] = norm * [cam.fx, cam.fy] + [cam.cx, cam.cy]
    return out


def linear_rows(xy_undistorted: np.ndarray, P: np.ndarray) -> np.ndarray:
    """The two rows ``x p3 - p1``, ``y p3 - p2`` of each observation (Hartley & Sturm 1997), each scaled to unit length
    so that every view weighs alike; NaN where not observed.  (view, point, 2), (view, 3, 4) -> (view, point, 2, 4)"""
    rows = xy_undistorted[..., None] * P[:, None, 2:3, :] - P[:, None, :2, :]  # (view, point, 2, 4)
    return rows / np.linalg.norm(rows, axis=-1, keepdims=True)


def solve_linear(rows: np.ndarray) -> np.ndarray:
    """Linear-LS (Hartley & Sturm 1997): the point ``(x, y, z)`` minimising ``|A (x, y, z, 1)|`` of each stacked system
    ``A`` (all-zero rows are views left out); NaN where the rows do not fix a point.  (..., rows, 4) -> (..., 3)"""
    a = rows[..., :3]  # (..., rows, 3)
    normal = np.swapaxes(a, -1, -2) @ a  # (..., 3, 3) normal equations A^T A x = -A^T a4
    rhs = -(np.swapaxes(a, -1, -2) @ rows[..., 3:])[..., 0]  # (..., 3)
    return _solve_symmetric3(normal, rhs)


def _solve_symmetric3(m: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``m^-1 b`` of symmetric positive semi-definite 3x3 systems by their adjugate (closed form, elementwise: several
    times faster than a batched LAPACK solve of small systems); NaN where ``m`` is singular or not finite.
    (..., 3, 3), (..., 3) -> (..., 3)"""
    m00, m01, m02, m11, m12, m22 = (m[..., i, j] for i, j in ((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2)))
    c00, c01, c02 = m11 * m22 - m12 * m12, m02 * m12 - m01 * m22, m01 * m12 - m02 * m11
    c11, c12, c22 = m00 * m22 - m02 * m02, m01 * m02 - m00 * m12, m00 * m11 - m01 * m01
    det = m00 * c00 + m01 * c01 + m02 * c02  # (...,)
    scale = (m00 + m11 + m22) ** 3
    solvable = np.isfinite(det) & (det > 1e-12 * scale)  # condition number below about 1e12
    with np.errstate(divide="ignore", invalid="ignore"):
        x = np.stack([c00 * b[..., 0] + c01 * b[..., 1] + c02 * b[..., 2],
                      c01 * b[..., 0] + c11 * b[..., 1] + c12 * b[..., 2],
                      c02 * b[..., 0] + c12 * b[..., 1] + c22 * b[..., 2]], axis=-1) / det[..., None]
    return np.where(solvable[..., None], x, np.nan)


def triangulate_linear(xy_undistorted: np.ndarray, P: np.ndarray, mask: np.ndarray | None = None) -> np.ndarray:
    """Linear-LS points from the views of ``mask`` (default: every view that observes a point); NaN where fewer than
    two views are used.  (view, point, 2) undistorted pixels, (view, 3, 4), (view, point) -> (point, 3)"""
    use = claimed(xy_undistorted, mask)  # (view, point)
    if P.shape != (use.shape[0], 3, 4):
        raise TriangulationError(f"P must hold one 3x4 projection matrix per view, shape ({use.shape[0]}, 3, 4); "
                                 f"got {P.shape}")
    rows = np.where(use[..., None, None], linear_rows(np.where(use[..., None], xy_undistorted, 0.0), P), 0.0)
    stacked = rows.transpose(1, 0, 2, 3).reshape(use.shape[1], -1, 4)  # (point, 2 view, 4)
    points = solve_linear(stacked)
    points[use.sum(axis=0) < 2] = np.nan
    return points


def project_points(points: np.ndarray, cameras: Sequence[Camera]) -> np.ndarray:
    """Distorted pixels of world points in every camera; NaN where a point lies behind a camera or is not finite.
    (point, 3) -> (view, point, 2)"""
    return np.stack([cam.project(np.asarray(points, dtype=np.float64))[0] for cam in cameras])


def reprojection_errors(points: np.ndarray, xy: np.ndarray, cameras: Sequence[Camera]) -> np.ndarray:
    """Pixel distance between each observation and its point's projection through the full camera model; NaN where
    the view does not observe the point, inf where it does but the point is behind that camera or not finite.
    (point, 3), (view, point, 2) -> (view, point)"""
    xy = check_observations(xy, cameras)
    _check_points(points, xy.shape[1])
    offset = project_points(points, cameras) - xy  # (view, point, 2)
    errors = np.hypot(offset[..., 0], offset[..., 1])  # (view, point)
    seen = claimed(xy)
    return np.where(seen, np.where(np.isfinite(errors), errors, np.inf), np.nan)


def refine_points(points: np.ndarray, xy: np.ndarray, cameras: Sequence[Camera], mask: np.ndarray | None = None,
                  config: RefineConfig = RefineConfig()) -> np.ndarray:
    """Points minimising the sum of squared reprojection errors (distorted pixels, full OpenCV model) over the views of
    ``mask`` (default: every observing view), each point on its own, all at once: Levenberg-Marquardt with one damping
    factor per point, a step kept only where it lowers that point's error. Points with fewer than two views or not
    finite are returned as given.  (point, 3), (view, point, 2), (view, point) -> (point, 3)"""
    xy = check_observations(xy, cameras)
    points = _check_points(points, xy.shape[1])
    use = claimed(xy, mask)
    active = np.flatnonzero(np.isfinite(points).all(axis=1) & (use.sum(axis=0) >= 2))
    current, obs, use = points[active].copy(), xy[:, active], use[:, active]
    cost, hessian, gradient = _normal_equations(current, obs, use, cameras)
    damping = np.full(len(active), config.damping)
    live = np.arange(len(active))  # points still moving
    for _ in range(config.max_iterations):
        if live.size == 0:
            break
        step = _damped_steps(hessian[live], gradient[live], damping[live])  # (live, 3)
        trial = current[live] + step
        trial_cost, trial_hessian, trial_gradient = _normal_equations(trial, obs[:, live], use[:, live], cameras)
        better = trial_cost < cost[live]  # (live,)
        won = live[better]
        current[won], cost[won] = trial[better], trial_cost[better]
        hessian[won], gradient[won] = trial_hessian[better], trial_gradient[better]
        damping[live] *= np.where(better, 0.1, 10.0)
        live = live[np.abs(step).max(axis=1) > config.step_tol_m]
    refined = points.copy()
    refined[active] = current
    return refined


def _normal_equations(points: np.ndarray, xy: np.ndarray, use: np.ndarray, cameras: Sequence[Camera]):
    """Sum of squared residuals (inf where a point is behind a used camera), Gauss-Newton matrix J^T J and gradient
    J^T r of each point over its used views.  (n, 3), (view, n, 2), (view, n) -> (n,), (n, 3, 3), (n, 3)"""
    view, point = np.nonzero(use)  # (obs,) sorted by view
    bounds = np.searchsorted(view, np.arange(len(cameras) + 1))
    residual, jacobian = np.zeros((len(view), 2)), np.zeros((len(view), 2, 3))
    behind = np.zeros(len(view), dtype=bool)
    for v, cam in enumerate(cameras):
        obs = slice(bounds[v], bounds[v + 1])
        if bounds[v] == bounds[v + 1]:
            continue
        w2c = cam.world_to_cam
        in_cam = points[point[obs]] @ w2c[:3, :3].T + w2c[:3, 3]  # (k, 3)
        uv, jac = cv2.projectPoints(in_cam.reshape(-1, 1, 3), _ZERO3, _ZERO3, cam.K, np.asarray(cam.dist))
        residual[obs] = uv.reshape(-1, 2) - xy[v, point[obs]]
        jacobian[obs] = jac[:, 3:6].reshape(-1, 2, 3) @ w2c[:3, :3]  # d pixel / d world point (the tvec columns)
        behind[obs] = ~(in_cam[:, 2] > 0)
    jt = np.swapaxes(jacobian, 1, 2)  # (obs, 3, 2)
    cost = np.where(behind, np.inf, (residual**2).sum(axis=1))  # (obs,)
    per_obs = np.column_stack([cost, (jt @ jacobian).reshape(-1, 9), (jt @ residual[..., None])[..., 0]])  # (obs, 13)
    summed = csr_matrix((np.ones(len(view)), (point, np.arange(len(view)))), shape=(len(points), len(view))) @ per_obs
    return summed[:, 0], summed[:, 1:10].reshape(-1, 3, 3), summed[:, 10:]


def _damped_steps(hessian: np.ndarray, gradient: np.ndarray, damping: np.ndarray) -> np.ndarray:
    """Levenberg-Marquardt steps ``-(H + damping diag H)^-1 g`` per point; zero where the system is singular.
    (n, 3, 3), (n, 3), (n,) -> (n, 3)"""
    diag = np.diagonal(hessian, axis1=1, axis2=2)  # (n, 3)
    damped = hessian + (damping[:, None] * diag)[:, :, None] * np.eye(3)
    steps = -_solve_symmetric3(damped, gradient)
    return np.where(np.isfinite(steps), steps, 0.0)


def _check_points(points: np.ndarray, count: int) -> np.ndarray:
    points = np.asarray(points, dtype=np.float64)
    if points.shape != (count, 3):
        raise TriangulationError(f"points must have shape (point, 3) = ({count}, 3) to match the observations, "
                                 f"got {points.shape}")
    return points

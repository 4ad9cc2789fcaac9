"""Speed and accuracy of the suit's corner reconstruction (`tasks/suit/reconstruct.py`) on synthetic frames: corners
in a 1 m cube seen by a ring of calibrated cameras (2048x1536, fx 1800, lens distortion), each corner claimed by a
random 3-8 of the views with 0.2 px noise, a share of the claims planted wrong (20-200 px off). Prints one JSON line:
the median milliseconds per frame (wall clock, and CPU time of the process), the median 3D error and how the planted
claims fared.

    taskset -c 0 python benchmarks/suit_reconstruct.py [--corners 1500 --views 12 --wrong 0.05 --runs 7]

``--compare-scipy`` also times (CPU, median of 3) the final nonlinear refinement both ways on the last frame: the
per-point Levenberg-Marquardt of ``tasks.shared.triangulation.refine_points`` and ``scipy.optimize.least_squares``
with a block-diagonal ``jac_sparsity``.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import time

for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(var, "1")

import cv2  # noqa: E402
import numpy as np  # noqa: E402
from scipy.optimize import least_squares  # noqa: E402
from scipy.sparse import csr_matrix  # noqa: E402

from mocapflow.tasks.shared.cameras import calibrated_camera  # noqa: E402
from mocapflow.tasks.shared.triangulation import (  # noqa: E402
    project_points,
    projection_matrices,
    refine_points,
    triangulate_linear,
    undistort_pixels,
)
from mocapflow.tasks.shared.cameras import look_at, ring_positions  # noqa: E402
from mocapflow.tasks.suit.reconstruct import reconstruct_frame  # noqa: E402

DIST = (-0.25, 0.12, 0.0005, -0.0003, -0.02)
CENTRE = (0.0, 0.0, 1.0)


def cameras(views: int):
    return [calibrated_camera(f"cam{i}", fx=1800.0, fy=1795.0, cx=1023.5, cy=767.5, dist=DIST,
                              cam_to_world=look_at(p, CENTRE), width=2048, height=1536)
            for i, p in enumerate(ring_positions(views, radius=2.5, height=1.6))]


def frame(cams, corners: int, wrong: float, rng: np.random.Generator):
    """True points (corner, 3), claimed pixels (view, corner, 2) and which claims are wrong (view, corner)."""
    points = rng.uniform(-0.5, 0.5, (corners, 3)) + CENTRE
    xy = project_points(points, cams) + rng.normal(0.0, 0.2, (len(cams), corners, 2))
    claims = np.zeros((len(cams), corners), bool)
    for c, n in enumerate(rng.integers(3, 9, corners)):
        claims[rng.choice(len(cams), n, replace=False), c] = True
    planted = claims & (rng.random(claims.shape) < wrong)
    angle, radius = rng.uniform(0, 2 * np.pi, claims.shape), rng.uniform(20, 200, claims.shape)
    xy += planted[..., None] * radius[..., None] * np.stack([np.cos(angle), np.sin(angle)], axis=-1)
    xy[~claims] = np.nan
    return points, xy, planted


def refine_scipy(points, xy, cams, mask):
    """``least_squares`` over all points at once with a block-diagonal Jacobian sparsity (3 unknowns per point)."""
    view, point = np.nonzero(mask)  # (observation,)
    rotations = [cam.world_to_cam for cam in cams]
    by_view = [np.flatnonzero(view == v) for v in range(len(cams))]

    def residuals(flat):
        world = flat.reshape(-1, 3)
        out = np.empty((len(view), 2))
        for v, (cam, w2c, obs) in enumerate(zip(cams, rotations, by_view)):
            in_cam = world[point[obs]] @ w2c[:3, :3].T + w2c[:3, 3]
            uv = cv2.projectPoints(in_cam.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), cam.K, np.asarray(cam.dist))[0]
            out[obs] = uv.reshape(-1, 2) - xy[v, point[obs]]
        return out.ravel()

    rows = np.repeat(np.arange(2 * len(view)), 3)
    cols = (3 * np.repeat(point, 2)[:, None] + np.arange(3)).ravel()
    sparsity = csr_matrix((np.ones(len(rows)), (rows, cols)), shape=(2 * len(view), 3 * len(points)))
    return least_squares(residuals, points.ravel(), jac_sparsity=sparsity, method="trf").x.reshape(-1, 3)


def compare_refinement(cams, xy, kept) -> dict:
    start = triangulate_linear(undistort_pixels(xy, cams), projection_matrices(cams), kept)
    used = np.isfinite(start).all(axis=1)
    times, results = {}, {}
    for name, refine in (("levenberg_marquardt", lambda: refine_points(start, xy, cams, kept)),
                         ("scipy_least_squares", lambda: refine_scipy(start[used], xy[:, used], cams, kept[:, used]))):
        spent = []
        for _ in range(3):
            cpu = time.process_time()
            results[name] = refine()
            spent.append(1000 * (time.process_time() - cpu))
        times[name] = round(statistics.median(spent), 2)
    gap = np.abs(results["levenberg_marquardt"][used] - results["scipy_least_squares"]).max()
    return {"refine_cpu_ms": times, "refine_max_difference_mm": round(1000 * float(gap), 5)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--corners", type=int, default=1500)
    parser.add_argument("--views", type=int, default=12)
    parser.add_argument("--wrong", type=float, default=0.05, help="share of the claims planted wrong")
    parser.add_argument("--runs", type=int, default=7, help="frames timed (a new random frame each)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--compare-scipy", action="store_true")
    args = parser.parse_args()
    rng, cams = np.random.default_rng(args.seed), cameras(args.views)
    times, cpu_times, errors, kept_wrong, dropped_right, planted_all, reconstructed = [], [], [], 0, 0, 0, []
    for _ in range(args.runs):
        points, xy, planted = frame(cams, args.corners, args.wrong, rng)
        t, cpu = time.perf_counter(), time.process_time()
        result = reconstruct_frame(xy, cams)
        times.append(1000 * (time.perf_counter() - t))
        cpu_times.append(1000 * (time.process_time() - cpu))
        distance = np.linalg.norm(result.position - points, axis=1)
        errors.append(distance[np.isfinite(distance)])
        reconstructed.append(float(np.isfinite(distance).mean()))
        kept_wrong += int((result.kept & planted).sum())
        dropped_right += int((~result.kept & np.isfinite(xy).all(-1) & ~planted).sum())
        planted_all += int(planted.sum())
    errors = np.concatenate(errors)
    report = {"ms_per_frame_median": round(statistics.median(times), 2),
              "ms_per_frame_all": [round(t, 1) for t in times],
              "cpu_ms_per_frame_median": round(statistics.median(cpu_times), 2),
              "corners": args.corners, "views": args.views, "wrong_share": args.wrong, "runs": args.runs,
              "reconstructed_share": round(statistics.mean(reconstructed), 4),
              "error_mm_median": round(1000 * float(np.median(errors)), 4),
              "error_mm_p99": round(1000 * float(np.percentile(errors, 99)), 4),
              "planted_claims": planted_all, "planted_kept": kept_wrong, "right_claims_dropped": dropped_right}
    if args.compare_scipy:
        report.update(compare_refinement(cams, xy, result.kept))
    print(json.dumps(report))


if __name__ == "__main__":
    main()

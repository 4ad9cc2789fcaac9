"""Accuracy against the studio's ground truth, as pure functions of arrays.

Scene flow (DeepMoCap §3.2 input): the 3D end-point error (EPE) of the estimated camera-frame
motion from frame f-1 to f against the true motion of the surface seen at each pixel of frame f,
on visible body pixels whose depth is valid (the estimator cannot see anything else), and the
coverage: the fraction of those pixels the estimator reports a motion for.
"""

from __future__ import annotations

import numpy as np


def flow_errors(flow: np.ndarray, valid: np.ndarray, gt_flow: np.ndarray, gt_body: np.ndarray,
                depth: np.ndarray, first_frame: np.ndarray) -> tuple[np.ndarray, int]:
    """End-point errors (mm) of the reported pixels, and how many pixels could have been reported.

    flow, gt_flow (frame, y, x, 3) metres; valid, gt_body (frame, y, x) bool; depth (frame, y, x) mm;
    first_frame (frame,) bool marks frames without a predecessor. -> errors (n,) float32, eligible int
    """
    eligible = gt_body & (depth > 0) & ~first_frame[:, None, None]
    reported = eligible & valid
    err = np.linalg.norm(flow[reported].astype(np.float32) - gt_flow[reported].astype(np.float32), axis=-1)
    return 1000.0 * err, int(eligible.sum())


def summarize_flow(errors: np.ndarray, eligible: int) -> dict[str, float]:
    """EPE mean (the usual EPE), median and 90th percentile in mm, and coverage."""
    if errors.size == 0:
        return {"epe_mean_mm": float("nan"), "epe_median_mm": float("nan"), "epe_p90_mm": float("nan"),
                "coverage": 0.0, "pixels": 0}
    return {"epe_mean_mm": float(errors.mean()), "epe_median_mm": float(np.median(errors)),
            "epe_p90_mm": float(np.percentile(errors, 90)), "coverage": errors.size / max(eligible, 1),
            "pixels": int(errors.size)}

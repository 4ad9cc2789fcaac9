"""Accuracy against the studio's ground truth, as pure functions of arrays.

Scene flow (DeepMoCap §3.2 input): the 3D end-point error (EPE) of the estimated camera-frame
motion from frame f-1 to f against the true motion of the surface seen at each pixel of frame f,
on visible body pixels whose depth is valid (the estimator cannot see anything else), and the
coverage: the fraction of those pixels the estimator reports a motion for.
"""

from __future__ import annotations

import numpy as np

from mocapflow.tasks.shared.marker_errors import tail



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


# 2D reflector estimation (DeepMoCap §5.1.2): an estimate is correct when it lies within
# alpha x the subject's bounding-box size (PCK, alpha = 0.05) of the true position of that reflector.
# Positives are reflectors with at least ``min_pixels`` visible pixels; an estimate of a reflector
# that shows fewer pixels but more than none is neither right nor wrong (it is ignored, as a
# "difficult" instance); anything else is a false positive.

END_REFLECTORS = ("R_HAND", "L_HAND", "R_FOOT", "L_FOOT")  # the ends of the limb chains


class Matches2D:
    """Per reflector: the confidence and correctness of every scored estimate, and the positives."""

    def __init__(self, n_reflectors: int):
        self.confidence: list[list[float]] = [[] for _ in range(n_reflectors)]
        self.correct: list[list[bool]] = [[] for _ in range(n_reflectors)]
        self.positives = np.zeros(n_reflectors, np.int64)


def pck_radius(body: np.ndarray, alpha: float = 0.05) -> float:
    """alpha x the longer side of the subject's bounding box in one image.  (y, x) bool -> px"""
    ys, xs = np.nonzero(body)
    if len(xs) == 0:
        return 0.0
    return alpha * float(max(xs.max() - xs.min() + 1, ys.max() - ys.min() + 1))


def match_2d(matches: Matches2D, xy: np.ndarray, confidence: np.ndarray, gt_xy: np.ndarray, gt_pixels: np.ndarray,
             radius: float, *, min_pixels: int = 5) -> None:
    """Score one image's estimates into ``matches``.  xy, gt_xy (R, 2) px (NaN: no estimate); (R,) each"""
    positive = gt_pixels >= min_pixels
    matches.positives += positive
    distance = np.linalg.norm(xy - gt_xy, axis=1)
    for r in np.nonzero(np.isfinite(xy[:, 0]))[0]:
        near = distance[r] <= radius
        if near and 0 < gt_pixels[r] < min_pixels:
            continue  # barely visible: ignored
        matches.confidence[r].append(float(confidence[r]))
        matches.correct[r].append(bool(near and positive[r]))


def average_precision(confidence, correct, positives: int) -> float:
    """Area under the precision-recall curve (all points, precision made monotone), NaN without positives."""
    if positives == 0:
        return float("nan")
    order = np.argsort(-np.asarray(confidence, float), kind="stable")
    hits = np.asarray(correct, bool)[order]
    tp = np.cumsum(hits)
    precision = tp / np.arange(1, len(hits) + 1)
    recall = tp / positives
    envelope = np.maximum.accumulate(precision[::-1])[::-1] if len(hits) else precision
    steps = np.diff(np.concatenate([[0.0], recall]))
    return float((envelope * steps).sum())


def summarize_2d(matches: Matches2D, names, c_min: float = 0.0) -> dict:
    """AP per reflector, mAP (with and without end-reflectors), precision and recall of estimates >= c_min."""
    ap, tp, n_est = {}, 0, 0
    for r, name in enumerate(names):
        conf = np.asarray(matches.confidence[r], float)
        hit = np.asarray(matches.correct[r], bool)
        kept = conf >= c_min
        ap[name] = average_precision(conf[kept], hit[kept], int(matches.positives[r]))
        tp += int(hit[kept].sum())
        n_est += int(kept.sum())
    values = np.array([ap[n] for n in names])
    core = np.array([ap[n] for n in names if n not in END_REFLECTORS])
    return {"ap": ap, "map": float(np.nanmean(values)), "map_no_end": float(np.nanmean(core)),
            "precision": tp / max(n_est, 1), "recall": tp / max(int(matches.positives.sum()), 1),
            "estimates": n_est, "positives": int(matches.positives.sum())}


# 3D optical data (DeepMoCap §3.4): per-reflector error against the studio's ground truth (a strap's
# ground truth is the limb centre at the strap, a patch's the tape's centre), completeness and jitter.

def jitter(xyz: np.ndarray, fps: float) -> float:
    """Mean acceleration magnitude (m/s^2) over frames whose neighbours are observed too.  (frame, reflector, 3)"""
    acc = (xyz[2:] - 2 * xyz[1:-1] + xyz[:-2]) * fps**2
    norms = np.linalg.norm(acc, axis=-1)
    return float(np.nanmean(norms)) if np.isfinite(norms).any() else float("nan")


def summarize_markers(errors: np.ndarray, names, *, jitter_value: float = float("nan"),
                      gt_jitter: float = float("nan")) -> dict:
    """Median, mean error (mm), the tail (p95, p99, share > 10 cm of the marker-frames with a value),
    completeness (fraction of frame x reflector with a value), per reflector."""
    seen = np.isfinite(errors)
    values = errors[seen]
    per = {str(n): float(np.median(errors[:, r][seen[:, r]])) if seen[:, r].any() else float("nan")
           for r, n in enumerate(names)}
    return {"median_mm": float(np.median(values)) if values.size else float("nan"),
            "mean_mm": float(values.mean()) if values.size else float("nan"),
            **tail(values), "completeness": float(seen.mean()), "jitter_ms2": jitter_value, "gt_jitter_ms2": gt_jitter,
            "per_reflector_median_mm": per}


# Motion capture (DeepMoCap §5.3, Tables 6-8, Fig. 14): 3D joint error on the 12 joints of Table 8.
# An unsolved joint (NaN) counts as a miss in PCK and is left out of MAE and RMSE.

TABLE8_JOINTS = ("LeftShoulder", "RightShoulder", "LeftElbow", "RightElbow", "LeftHand", "RightHand",
                 "LeftHip", "RightHip", "LeftKnee", "RightKnee", "LeftFoot", "RightFoot")
PCK_CURVE_CM = tuple(float(t) for t in range(0, 21))


def joint_errors(position: np.ndarray, gt: np.ndarray) -> np.ndarray:
    """Distances in cm, NaN where unsolved.  (frame, joint, 3) m x2 -> (frame, joint)"""
    return 100.0 * np.linalg.norm(position.astype(np.float64) - gt.astype(np.float64), axis=-1)


def pck(errors: np.ndarray, threshold_cm: float) -> float:
    """Fraction of (frame, joint) within ``threshold_cm``; NaN (unsolved) counts as a miss."""
    return float(np.mean(np.nan_to_num(errors, nan=np.inf) <= threshold_cm)) if errors.size else float("nan")


def summarize_joints(errors: np.ndarray, names) -> dict:
    """MAE, RMSE (cm), 3D PCK at 5 and 20 cm, the PCK curve over 0-20 cm, per joint.  (frame, joint) cm"""
    solved = errors[np.isfinite(errors)]
    per = {str(n): {"mae_cm": float(np.nanmean(errors[:, j])) if np.isfinite(errors[:, j]).any() else float("nan"),
                    "pck_20cm": pck(errors[:, j], 20.0), "pck_5cm": pck(errors[:, j], 5.0)}
           for j, n in enumerate(names)}
    return {"mae_cm": float(solved.mean()) if solved.size else float("nan"),
            "rmse_cm": float(np.sqrt(np.mean(solved**2))) if solved.size else float("nan"),
            "median_cm": float(np.median(solved)) if solved.size else float("nan"),
            "pck_20cm": pck(errors, 20.0), "pck_5cm": pck(errors, 5.0),
            "solved": float(np.isfinite(errors).mean()) if errors.size else float("nan"),
            "curve": {t: pck(errors, t) for t in PCK_CURVE_CM}, "per_joint": per}

"""Figures of the suit chain, drawn with OpenCV: labelled corners and codes over a camera image, the filled suit
in 3D (observed corners green, filled ones orange) from two sides, and the reprojection errors' histogram."""

from __future__ import annotations

import cv2
import numpy as np

GREEN, ORANGE, WHITE, GREY, RED = (60, 200, 60), (0, 140, 255), (255, 255, 255), (120, 120, 120), (40, 40, 230)
FONT = cv2.FONT_HERSHEY_SIMPLEX


def overlay_labels(image: np.ndarray, xy: np.ndarray, square_corners: np.ndarray, codes, truth: np.ndarray | None = None,
                   box: tuple[int, int, int, int] | None = None) -> np.ndarray:
    """A grey image (y, x) with its labelled corners (green dots; a label more than 2 px from the truth red), each
    coded square whose four corners are labelled outlined with its code, and the true visible corners as grey rings.
    xy (corner, 2) NaN where not labelled; truth (corner, 2) NaN where not visible; box (y0, y1, x0, x1) crops."""
    y0, y1, x0, x1 = box or (0, image.shape[0], 0, image.shape[1])
    scale = max(1, int(round(900 / max(y1 - y0, x1 - x0))))
    out = cv2.cvtColor(image[y0:y1, x0:x1], cv2.COLOR_GRAY2BGR)
    out = cv2.resize(out, None, fx=scale, fy=scale, interpolation=cv2.INTER_NEAREST)

    def px(p):
        return (int(round((p[0] - x0 + 0.5) * scale - 0.5)), int(round((p[1] - y0 + 0.5) * scale - 0.5)))

    if truth is not None:
        for p in truth[np.isfinite(truth).all(axis=1)]:
            cv2.circle(out, px(p), 2 * scale, GREY, 1, cv2.LINE_AA)
    for quad, code in zip(square_corners, codes):
        q = xy[quad]
        if np.isfinite(q).all():
            cv2.polylines(out, [np.array([px(p) for p in q], np.int32)], True, GREEN, 1, cv2.LINE_AA)
            cv2.putText(out, str(code), px(q.mean(axis=0)), FONT, 0.25 * scale, ORANGE, 1, cv2.LINE_AA)
    labelled = np.isfinite(xy).all(axis=1)
    wrong = np.zeros(len(xy), bool) if truth is None else labelled & ~(
        np.linalg.norm(np.nan_to_num(xy - truth, nan=1e9), axis=1) <= 2.0)
    for c in np.flatnonzero(labelled):
        cv2.circle(out, px(xy[c]), max(2, scale), RED if wrong[c] else GREEN, -1, cv2.LINE_AA)
    return out


def view_3d(points: np.ndarray, observed: np.ndarray, cells: np.ndarray, size: int = 600) -> np.ndarray:
    """The suit's corners (corner, 3) from the front and the side, its corner mesh's edges in grey, observed corners
    green and filled ones orange; observed (corner,) bool; cells (cell, 4)."""
    panels = []
    for axis in (0, 1):  # front: x across, z up; side: y across, z up
        ok = np.isfinite(points).all(axis=1)
        centre = (points[ok].min(axis=0) + points[ok].max(axis=0)) / 2
        span = max(np.ptp(points[ok][:, 2]), 1e-3) * 1.1
        u = (points[:, axis] - centre[axis]) / span * size + size / 2
        v = size / 2 - (points[:, 2] - centre[2]) / span * size
        panel = np.full((size, size, 3), 24, np.uint8)
        for cell in cells:
            if ok[cell].all():
                cv2.polylines(panel, [np.column_stack([u[cell], v[cell]]).astype(np.int32)], True, GREY, 1,
                              cv2.LINE_AA)
        for c in np.flatnonzero(ok):
            cv2.circle(panel, (int(u[c]), int(v[c])), 2, GREEN if observed[c] else ORANGE, -1, cv2.LINE_AA)
        cv2.putText(panel, "front" if axis == 0 else "side", (10, 24), FONT, 0.6, WHITE, 1, cv2.LINE_AA)
        panels.append(panel)
    out = np.concatenate(panels, axis=1)
    cv2.putText(out, f"observed {int(observed.sum())}  filled {int((~observed).sum())}", (10, size - 12), FONT, 0.55,
                WHITE, 1, cv2.LINE_AA)
    return out


def histogram(values: np.ndarray, top: float, title: str, bins: int = 40, size: tuple[int, int] = (360, 640)) -> np.ndarray:
    """A histogram of ``values`` over [0, top] with its median, p95 and p99 marked."""
    h, w = size
    counts, _ = np.histogram(np.clip(values, 0, top), bins=bins, range=(0, top))
    out = np.full((h, w, 3), 255, np.uint8)
    left, bottom, width, height = 50, h - 40, w - 70, h - 80
    for i, c in enumerate(counts):
        bar = int(height * c / max(counts.max(), 1))
        x = left + int(i * width / bins)
        cv2.rectangle(out, (x, bottom - bar), (left + int((i + 1) * width / bins) - 1, bottom), (160, 120, 60), -1)
    for q, colour in ((50, GREEN), (95, ORANGE), (99, RED)):
        value = float(np.percentile(values, q)) if len(values) else 0.0
        x = left + int(min(value, top) / top * width)
        cv2.line(out, (x, bottom - height), (x, bottom), colour, 1)
        cv2.putText(out, f"p{q} {value:.2f}", (x + 3, bottom - height + 14 * (q // 50)), FONT, 0.4, colour, 1,
                    cv2.LINE_AA)
    cv2.line(out, (left, bottom), (left + width, bottom), (0, 0, 0), 1)
    for t in np.linspace(0, top, 5):
        x = left + int(t / top * width)
        cv2.putText(out, f"{t:g}", (x - 8, bottom + 18), FONT, 0.4, (0, 0, 0), 1, cv2.LINE_AA)
    cv2.putText(out, title, (left, 22), FONT, 0.5, (0, 0, 0), 1, cv2.LINE_AA)
    return out

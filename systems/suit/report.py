"""The suit in `mocapflow report`, and its figures drawn with OpenCV: labelled corners and codes over a camera image,
the filled suit in 3D (observed corners green, filled ones orange) from two sides, and the errors' histograms.

Its takes are the suit's corners (the filled ones where the catalog fills, else the triangulated ones) as markers,
with the studio's true corners where the take has them; a suit has about 1,400 corners, so a take carries an even
subsample of them (``TAKE_CORNERS`` at most, said on the page) for the marker table, trajectories and 3D view, while
the figures draw every corner.
"""

from __future__ import annotations

from math import ceil
from pathlib import Path

import cv2
import numpy as np

from mocapflow.pipeline.catalog import stage_writing
from mocapflow.pipeline.registry import ReportSection
from mocapflow.presentation.report import Take, write_png
from mocapflow.systems.suit.export import corner_names

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


# ---- the report section ----------------------------------------------------------------------------------------

TAKE_CORNERS = 150  # corners a take carries at most into the page's table, trajectories and 3D view


def corner_stage(catalog) -> str | None:
    """The corners to show: the catalog's last filling, else its last triangulation (not a hold-out's)."""
    return stage_writing(catalog, "suit_filled") or stage_writing(catalog, "suit_points")


def applies(catalog) -> bool:
    return corner_stage(catalog) is not None and stage_writing(catalog, "suit_images") is not None


def takes(catalog, plan, store) -> list[Take]:
    """Every sequence's corners (an even subsample, ``TAKE_CORNERS`` at most) named by code and quad vertex, with
    the studio's true corners where the take has them."""
    stage, source = corner_stage(catalog), stage_writing(catalog, "suit_images")
    out = []
    for seq in plan.sequences:
        corners, images = plan.open(store, stage, seq.id), plan.open(store, source, seq.id)
        n = corners.sizes["corner"]
        step = max(1, ceil(n / TAKE_CORNERS))
        keep = np.arange(0, n, step)
        names = corner_names(images["code"].values, images["square_corners"].values, n)
        take = Take(seq.id, float(corners.attrs["fps"]), str(images.attrs.get("exercise", "")), stage,
                    [names[c] or f"corner{c}" for c in keep],
                    corners["position"].values[:, keep].astype(np.float64))
        if step > 1:
            take.note = (f"{len(keep)} of the {n} corners of the suit (every {step}th) in the table, trajectories and 3D "
                         "view; the figures above draw every corner")
        if "gt_corners" in images:
            take.gt_markers = images["gt_corners"].values[:, keep].astype(np.float64)
        out.append(take)
    return out


def figures(folder: Path, catalog, plan, store, result: dict) -> list[Path]:
    """Of the first sequence's middle frame: the labelled corners over the view that labels most
    (``suit_labels_<seq>.png``) and the suit in 3D (``suit_corners_3d_<seq>.png``); over every sequence the
    triangulation's reprojection errors and, with the truth, the corners' 3D errors (histograms)."""
    folder.mkdir(parents=True, exist_ok=True)
    seq, source = plan.sequences[0], stage_writing(catalog, "suit_images")
    images = plan.open(store, source, seq.id)
    frame = images.sizes["frame"] // 2
    out = []
    labels = stage_writing(catalog, "suit_labels")
    if labels is not None:
        out.append(folder / f"suit_labels_{seq.id}.png")
        write_png(out[-1], _labels_figure(plan, store, labels, seq, images, frame))
    out.append(folder / f"suit_corners_3d_{seq.id}.png")
    write_png(out[-1], _corners_figure(plan.open(store, corner_stage(catalog), seq.id).isel(frame=frame),
                                       images["cells"].values))
    return out + _histograms(folder, catalog, plan, store)


def _labels_figure(plan, store, stage: str, seq, images, frame: int) -> np.ndarray:
    """The view with the most labelled corners at ``frame``: its image cropped to the suit, labels and truth."""
    xys = {}
    for view in seq.views:
        lab = plan.open(store, stage, seq.id, view).sel(view=view).isel(frame=frame)
        xys[view] = np.stack([lab["x"].values, lab["y"].values], axis=1).astype(np.float64)
    view = max(xys, key=lambda v: int(np.isfinite(xys[v]).all(axis=1).sum()))
    pixels = images["image"].sel(view=view).isel(frame=frame).values
    truth = None
    if "gt_corners2d" in images:
        truth = images["gt_corners2d"].sel(view=view).isel(frame=frame).values.astype(np.float64)
        truth[~images["gt_visible"].sel(view=view).isel(frame=frame).values] = np.nan
    out = overlay_labels(pixels, xys[view], images["square_corners"].values, images["code"].values, truth,
                         _box(xys[view], pixels.shape))
    cv2.putText(out, f"{seq.id} {view}, frame {frame}: dots labelled (red: > 2 px off), rings the truth", (8, 20),
                FONT, 0.5, ORANGE, 1, cv2.LINE_AA)
    return out


def _box(xy: np.ndarray, shape: tuple[int, ...], margin: int = 20) -> tuple[int, int, int, int] | None:
    """(y0, y1, x0, x1) around the labelled corners, inside the image; None (the whole image) where none."""
    ok = np.isfinite(xy).all(axis=1)
    if not ok.any():
        return None
    (x0, y0), (x1, y1) = xy[ok].min(axis=0) - margin, xy[ok].max(axis=0) + margin
    return (max(0, int(y0)), min(shape[0], int(y1) + 1), max(0, int(x0)), min(shape[1], int(x1) + 1))


def _corners_figure(corners, cells: np.ndarray) -> np.ndarray:
    """One frame's corners in 3D; a triangulation's (no ``observed``) counts its reconstructed corners observed."""
    points = corners["position"].values.astype(np.float64)
    observed = corners["observed"].values if "observed" in corners else np.isfinite(points).all(axis=1)
    return view_3d(points, observed, cells)


def _histograms(folder: Path, catalog, plan, store) -> list[Path]:
    """The reprojection errors of the triangulation (px) and, with the truth, the shown corners' 3D errors (mm)."""
    out = []
    points = next((s.name for s in reversed(list(catalog.stages.values())) if s.spec.output == "suit_points"
                   and "suit_points" not in s.spec.inputs.values()), None)
    if points is not None:
        errors = [plan.open(store, points, seq.id) for seq in plan.sequences]
        values = np.concatenate([e["error"].values[e["kept"].values].ravel() for e in errors])
        values = values[np.isfinite(values)]
        if values.size:
            out.append(folder / "suit_reprojection_error.png")
            write_png(out[-1], histogram(values, _top(values, 1.0), f"reprojection error of the corners of {points} (px)"))
    source, stage = stage_writing(catalog, "suit_images"), corner_stage(catalog)
    if all("gt_corners" in plan.open(store, source, seq.id) for seq in plan.sequences):
        values = np.concatenate([_errors_mm(plan.open(store, stage, seq.id), plan.open(store, source, seq.id))
                                 for seq in plan.sequences])
        if values.size:
            out.append(folder / "suit_error_3d.png")
            write_png(out[-1], histogram(values, _top(values, 5.0), f"3D error of the corners of {stage} (mm)"))
    return out


def _errors_mm(corners, images) -> np.ndarray:
    error = np.linalg.norm(corners["position"].values.astype(np.float64) - images["gt_corners"].values, axis=-1)
    return 1000.0 * error[np.isfinite(error)]


def _top(values: np.ndarray, least: float) -> float:
    """The histogram's range: the 99th percentile rounded up to one significant digit, ``least`` at least."""
    p99 = float(np.percentile(values, 99))
    unit = 10.0 ** np.floor(np.log10(max(p99, 1e-9)))
    return max(least, float(np.ceil(p99 / unit) * unit))


# The evaluation's JSON keys, named for a reader: (label, scale, unit)
NAMED_FIGURES = {
    "suit_detect_rate": ("suit: readable corners labelled", 100, "%"),
    "suit_visible_rate": ("suit: visible corners labelled", 100, "%"), "suit_wrong_labels": ("suit: wrong labels", 1, ""),
    "suit_wrong_label_rate": ("suit: wrong labels, share of labels", 100, "%"),
    "suit_loc_err_px": ("suit: label localisation error, mean", 1, "px"),
    "suit_loc_err_all_median_px": ("suit: localisation error of every label, median", 1, "px"),
    "suit_loc_err_all_p99_px": ("suit: localisation error of every label, p99", 1, "px"),
    "suit_wrong_labels_in_3d": ("suit: wrong labels a triangulated corner was solved from", 1, ""),
    "suit_err3d_over_5mm": ("suit: triangulated corners over 5 mm off", 1, ""),
    "suit_err3d_median_mm": ("suit: triangulated corners' 3D error, median", 1, "mm"),
    "suit_err3d_perturbed_median_mm": ("suit: 3D error through perturbed calibration, median", 1, "mm"),
    "suit_fill_err_median_mm": ("suit: hidden corners filled, 3D error median", 1, "mm"),
    "suit_fill_occluded_median_mm": ("suit: occluded patches filled, 3D error median", 1, "mm"),
    "suit_fill_all_err_median_mm": ("suit: filled corners' 3D error, median", 1, "mm"),
}


# The studio's takes carry the true corners (``gt_corners``); a recording does not.
SECTION = ReportSection("suit", applies, takes, figures, NAMED_FIGURES,
                        truth="gt_corners")

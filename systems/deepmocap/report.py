"""DeepMoCap in `mocapflow report`: its takes (the exported markers, the fused views' evidence, the solved poses and
the studio's truth) and its accuracy figures (2D reflector estimates over each view's IR image, the solved
skeleton against the true one, the 3D PCK curve, the per-joint error), drawn with OpenCV; for every take, with or
without truth, the plausibility of each view's labels (tasks/deepmocap/consistency.py).
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import xarray as xr

from mocapflow.pipeline.catalog import final_stage, stage_writing
from mocapflow.pipeline.registry import ReportSection
from mocapflow.presentation.report import (FONT, SOLVED, TRUTH, WHITE, Take, bar_chart, base_takes, colour,
                                           line_plot, write_png)
from mocapflow.systems.deepmocap.evaluate import evaluate_plausibility, plausibility_stages, poses_stage
from mocapflow.tasks.shared.body import JOINT_NAMES, PARENTS

MARKER_SCHEMAS = ("smoothed_markers", "markers3d")  # the first a catalog writes is reported


def applies(catalog) -> bool:
    return any(stage_writing(catalog, schema) for schema in MARKER_SCHEMAS)


def takes(catalog, plan, store) -> list[Take]:
    """Every sequence of ``plan`` as the report shows it: the markers of the last stage writing one of
    ``MARKER_SCHEMAS`` (the plausibility-checked ones where there are), the views and residuals of the markers3d
    stage, the solved poses and the recording's ground-truth joints and reflectors (matched by name)."""
    stage = next((s for s in map(lambda schema: final_stage(catalog, schema), MARKER_SCHEMAS) if s), None)
    if stage is None:
        return []
    fused, poses = stage_writing(catalog, "markers3d"), poses_stage(catalog)
    source = next((s.name for s in catalog.stages.values() if s.spec.source), None)
    out = base_takes(catalog, plan, store, stage)
    for take in out:
        if fused is not None:
            f = plan.open(store, fused, take.id)
            take.views = f["views"].values
            residual = f["residual"].values  # (frame, marker, view), NaN where a view has no estimate
            counted = np.isfinite(residual).sum(-1)
            with np.errstate(invalid="ignore"):  # a view alone is its own fused point: no residual there
                take.residual = np.where(counted >= 2, np.nansum(residual, -1) / np.maximum(counted, 1), np.nan)
        if poses is not None:
            p = plan.open(store, poses, take.id).load()
            take.joints, take.joint_names = p["position"].values, [str(j) for j in p["joint"].values]
            take.parents = [int(i) for i in PARENTS] if take.joint_names == list(JOINT_NAMES) else []
        raw = plan.open(store, source, take.id) if source else None
        if raw is not None and "gt_joints" in raw and take.joints is not None:
            take.gt_joints = raw["gt_joints"].values
        if raw is not None and "gt_reflectors" in raw and set(take.names) <= set(raw["reflector"].values.tolist()):
            take.gt_markers = raw["gt_reflectors"].sel(reflector=take.names).values.astype(np.float64)
    return out


def overlay(ir: np.ndarray, xy: np.ndarray, gt_uv: np.ndarray, names: list[str], title: str,
            recovered: np.ndarray | None = None) -> np.ndarray:
    """IR image with estimated reflectors (filled, labelled; a ``recovered`` one a hollow dot) and the true ones
    (rings).  (y, x), (reflector, 2) x2, (reflector,) bool"""
    ir = ir.astype(np.float64)
    unsaturated = ir[ir < 0.5 * ir.max()] if (ir < 0.5 * ir.max()).any() else ir  # not the reflectors' regions
    top = max(float(np.percentile(unsaturated, 99.0)), 1.0)  # the body's IR sets the gain
    img = cv2.cvtColor(np.clip(ir / top * 255.0, 0, 255).astype(np.uint8), cv2.COLOR_GRAY2BGR)
    for r, name in enumerate(names):
        if np.isfinite(gt_uv[r]).all():
            cv2.circle(img, tuple(int(v) for v in gt_uv[r]), 6, WHITE, 1, cv2.LINE_AA)
        if np.isfinite(xy[r]).all():
            p = tuple(int(v) for v in xy[r])
            hollow = recovered is not None and recovered[r]
            cv2.circle(img, p, 3, colour(r, len(names)), 1 if hollow else -1, cv2.LINE_AA)
            cv2.putText(img, name, (p[0] + 4, p[1] - 4), FONT, 0.3, colour(r, len(names)), 1, cv2.LINE_AA)
    cv2.putText(img, title, (8, 20), FONT, 0.55, WHITE, 1, cv2.LINE_AA)
    if img.shape[0] >= 200:  # the legend, where the image has room for it
        legend = "dot: estimate (hollow: recovered)" + ("   ring: ground truth" if np.isfinite(gt_uv).any() else "")
        cv2.putText(img, legend, (8, img.shape[0] - 10), FONT, 0.4, WHITE, 1, cv2.LINE_AA)
    return img


def skeleton_panel(est: np.ndarray, gt: np.ndarray, title: str, size: int = 260) -> np.ndarray:
    """Front (x-z) and side (y-z) orthographic views of one frame's joints.  (joint, 3) x2 metres"""
    panels = []
    for axes, label in (((0, 2), "front"), ((1, 2), "side")):
        img = np.full((size, size, 3), 30, np.uint8)
        centre = np.nanmean(gt[:, axes], axis=0)
        scale = size / 2.3  # a 2.3 m field of view

        def to_px(p, centre=centre, scale=scale):
            return int(size / 2 + (p[0] - centre[0]) * scale), int(size / 2 - (p[1] - centre[1]) * scale)

        for joints, bgr, width in ((est, SOLVED, 4), (gt, TRUTH, 1)):  # the truth on top, thin: never hidden
            for j, parent in enumerate(PARENTS):
                if parent >= 0 and np.isfinite(joints[[j, parent]]).all():
                    cv2.line(img, to_px(joints[j, axes]), to_px(joints[parent, axes]), bgr, width, cv2.LINE_AA)
        cv2.putText(img, f"{title} {label}", (6, 16), FONT, 0.42, WHITE, 1, cv2.LINE_AA)
        cv2.putText(img, "solved", (6, size - 24), FONT, 0.4, SOLVED, 1, cv2.LINE_AA)
        cv2.putText(img, "ground truth", (6, size - 8), FONT, 0.4, TRUTH, 1, cv2.LINE_AA)
        panels.append(img)
    return np.hstack(panels)


def label_views(raw: xr.Dataset, reflectors: xr.Dataset, frame: int) -> np.ndarray:
    """Every view's image at ``frame`` with the labelled 2D reflectors over it, side by side (the true ones as
    rings where ``raw`` has them: a recording has none, and its labels are what a user judges)."""
    names = [str(n) for n in reflectors["reflector"].values]
    views = []
    for view in raw["view"].values:
        est = reflectors.sel(view=view).isel(frame=frame)
        seen = raw.sel(view=view).isel(frame=frame)
        uv = (np.where(seen["gt_visible"].values[:, None], seen["gt_reflectors2d"].values, np.nan)
              if "gt_reflectors2d" in seen else np.full((len(names), 2), np.nan))
        views.append(overlay(seen["ir"].values, np.stack([est["x"].values, est["y"].values], 1), uv, names,
                             f"{view}, frame {frame}", est["recovered"].values if "recovered" in est else None))
    return np.hstack(views)


def figures(folder: Path, raw: xr.Dataset, reflectors: xr.Dataset, poses: xr.Dataset, result: dict) -> list[Path]:
    """Write the report's PNGs for one sequence (``raw``, its 2D reflectors and poses) and the overall figures."""
    folder.mkdir(parents=True, exist_ok=True)
    out = [folder / "reflectors.png", folder / "skeleton.png", folder / "pck.png", folder / "joint_errors.png"]
    write_png(out[0], label_views(raw, reflectors, int(raw.sizes["frame"] // 2)))
    picks = np.linspace(0, poses.sizes["frame"] - 1, 4).round().astype(int)
    write_png(out[1], np.vstack([skeleton_panel(poses["position"].values[i], raw["gt_joints"].values[i],
                                                f"frame {i}") for i in picks]))
    p = result["poses"]
    curve_x = np.array(list(p["curve"]), float)
    curves = {"all joints": np.array(list(p["curve"].values()))}
    curves.update({name: np.array(list(e["curve"].values())) for name, e in p["per_exercise"].items()})
    write_png(out[2], line_plot(curve_x, {k: 100 * v for k, v in curves.items()}, title="3D PCK of the Table 8 joints",
                                xlabel="threshold (cm)", ylabel="correct (%)", y_max=100.0))
    write_png(out[3], bar_chart({n: j["mae_cm"] for n, j in p["per_joint"].items()}, title="mean 3D error per joint",
                                unit="cm"))
    return out


def accuracy_figures(folder: Path, catalog, plan, store, result: dict) -> list[Path]:
    """The DeepMoCap figures (2D estimates over IR, skeletons, PCK, per-joint error) of the first sequence, where
    the catalog has 2D reflectors and poses and the data ground truth; without ground truth (a recording), the
    labels over each view of every sequence's middle frame."""
    stage_2d, poses = stage_writing(catalog, "reflectors2d"), poses_stage(catalog)
    source = stage_writing(catalog, "raw_sequence")
    checked = plausibility_figure(folder, catalog, plan, store, result)
    if stage_2d is None or source is None:
        return checked

    def opened(seq):
        raw = plan.open(store, source, seq.id)
        return raw, xr.concat([plan.open(store, stage_2d, seq.id, v).sel(view=v).load() for v in seq.views], "view")

    if poses is not None and "poses" in result:
        raw, reflectors = opened(plan.sequences[0])
        return figures(folder, raw, reflectors, plan.open(store, poses, plan.sequences[0].id).load(), result) + checked
    folder.mkdir(parents=True, exist_ok=True)
    out = checked
    for seq in plan.sequences:
        raw, reflectors = opened(seq)
        out.append(folder / f"labels_{seq.id}.png")
        write_png(out[-1], label_views(raw, reflectors, int(raw.sizes["frame"] // 2)))
    return out


PLAUSIBILITY_BARS = (("agreement", "agree"), ("left_right", "left/right"), ("on_body", "on body"),
                     ("true_on_reflector", "on true refl."))  # the last only with truth


def plausibility_chart(plausibility: dict) -> np.ndarray:
    """One bar per view and check: the share (%) of the view's labels that pass it (over every sequence)."""
    values = {f"{view} {label}": 100 * f[key] for view, f in plausibility["views"].items()
              for key, label in PLAUSIBILITY_BARS if key in f}
    title = (f"labels per view: agree within {100 * plausibility['agreement_m']:g} cm, on their side, within "
             f"{100 * plausibility['on_body_m']:g} cm of the body")
    return bar_chart(values, title=title, unit="%", size=(640, 60 + 26 * len(values)))


def plausibility_figure(folder: Path, catalog, plan, store, result: dict) -> list[Path]:
    """``plausibility.png``, the plausibility of each view's labels: the evaluation's, or measured here where there
    is none (a recording: `mocapflow report` evaluates only takes with truth); nothing where the catalog lacks a
    markers3d stage or poses."""
    plausibility = result.get("plausibility")
    if plausibility is None and plausibility_stages(catalog) and plan.sequences:
        plausibility = evaluate_plausibility(catalog, plan, store, {seq.id: {} for seq in plan.sequences})
    if plausibility is None:
        return []
    folder.mkdir(parents=True, exist_ok=True)
    write_png(folder / "plausibility.png", plausibility_chart(plausibility))
    return [folder / "plausibility.png"]


# The evaluation's JSON keys, named for a reader: (label, scale, unit)
NAMED_FIGURES = {
    "pck3d_20cm": ("3D PCK @ 20 cm, Table 8 joints", 100, "%"),
    "pck3d_5cm": ("3D PCK @ 5 cm, Table 8 joints", 100, "%"), "mae3d_cm": ("3D joint MAE", 1, "cm"),
    "rmse3d_cm": ("3D joint RMSE", 1, "cm"), "poses_solved": ("frames solved", 100, "%"),
    "map2d": ("2D mAP, filtered", 100, "%"), "map2d_unfiltered": ("2D mAP, unfiltered", 100, "%"),
    "map2d_refined": ("2D mAP, refined from the poses", 100, "%"), "precision2d": ("2D precision", 100, "%"),
    "recall2d": ("2D recall", 100, "%"), "marker_err_median_mm": ("3D marker error, median (smoothed)", 1, "mm"),
    "marker_err_p95_mm": ("3D marker error, 95th percentile (smoothed)", 1, "mm"),
    "marker_completeness": ("3D markers present (smoothed)", 100, "%"),
    "smoothed_p99_mm": ("3D marker error, 99th percentile (smoothed)", 1, "mm"),
    "smoothed_gross_share": ("3D markers > 10 cm off (smoothed)", 100, "%"),
    "checked_p95_mm": ("3D marker error, 95th percentile (checked, exported)", 1, "mm"),
    "checked_p99_mm": ("3D marker error, 99th percentile (checked, exported)", 1, "mm"),
    "checked_gross_share": ("3D markers > 10 cm off (checked, exported)", 100, "%"),
    "marker_checked_completeness": ("3D markers present (checked, exported)", 100, "%"),
    "marker_fused_err_median_mm": ("3D marker error, median (fused)", 1, "mm"),
    "flow_epe_mm": ("scene flow end-point error, mean", 1, "mm"), "flow_coverage": ("scene flow coverage", 100, "%"),
    "plausibility_agreement": ("labels agreeing with another view", 100, "%"),
    "plausibility_left_right": ("labels on their side of the body", 100, "%"),
    "plausibility_on_body": ("labels on the body", 100, "%"),
    "plausibility_on_body_worst_view": ("labels on the body, worst view", 100, "%"),
}


# The studio's takes carry the true joints (``gt_joints``); a recording does not.
SECTION = ReportSection("deepmocap", applies, takes, accuracy_figures, NAMED_FIGURES,
                        truth="gt_joints")

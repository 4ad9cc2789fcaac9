"""The demo's report: PNG figures drawn with OpenCV and one HTML page that shows them with the figures.

Figures: labelled 2D reflector estimates over each view's IR image (ground truth as white rings),
the solved skeleton against the true one on a few frames (front and side views), the 3D PCK curve
over 0-20 cm and the per-joint mean error (Table 8 joints).
"""

from __future__ import annotations

import html
import os
from pathlib import Path

import cv2
import numpy as np
import xarray as xr

from mocapflow.pipeline.errors import StorageError
from mocapflow.tasks.shared.body import PARENTS

WHITE, GREY, BLACK = (255, 255, 255), (150, 150, 150), (0, 0, 0)
FONT = cv2.FONT_HERSHEY_SIMPLEX


def _colour(i: int, n: int) -> tuple[int, int, int]:
    hsv = np.uint8([[[int(180 * i / max(n, 1)), 220, 255]]])
    return tuple(int(c) for c in cv2.cvtColor(hsv, cv2.COLOR_HSV2BGR)[0, 0])


def overlay(ir: np.ndarray, xy: np.ndarray, gt_uv: np.ndarray, names: list[str], title: str,
            recovered: np.ndarray | None = None) -> np.ndarray:
    """IR image with estimated reflectors (filled, labelled; a ``recovered`` one a hollow dot) and the true ones
    (rings).  (y, x), (reflector, 2) x2, (reflector,) bool"""
    ir = ir.astype(np.float64)
    top = max(float(np.percentile(ir, 99.0)), 1.0)  # the body's IR, not the saturated reflectors, sets the gain
    img = cv2.cvtColor(np.clip(ir / top * 255.0, 0, 255).astype(np.uint8), cv2.COLOR_GRAY2BGR)
    for r, name in enumerate(names):
        if np.isfinite(gt_uv[r]).all():
            cv2.circle(img, tuple(int(v) for v in gt_uv[r]), 6, WHITE, 1, cv2.LINE_AA)
        if np.isfinite(xy[r]).all():
            p = tuple(int(v) for v in xy[r])
            hollow = recovered is not None and recovered[r]
            cv2.circle(img, p, 3, _colour(r, len(names)), 1 if hollow else -1, cv2.LINE_AA)
            cv2.putText(img, name, (p[0] + 4, p[1] - 4), FONT, 0.3, _colour(r, len(names)), 1, cv2.LINE_AA)
    cv2.putText(img, title, (8, 20), FONT, 0.55, WHITE, 1, cv2.LINE_AA)
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

        for joints, colour in ((gt, GREY), (est, (80, 200, 255))):
            for j, parent in enumerate(PARENTS):
                if parent >= 0 and np.isfinite(joints[[j, parent]]).all():
                    cv2.line(img, to_px(joints[j, axes]), to_px(joints[parent, axes]), colour, 2, cv2.LINE_AA)
        cv2.putText(img, f"{title} {label}", (6, 16), FONT, 0.42, WHITE, 1, cv2.LINE_AA)
        panels.append(img)
    return np.hstack(panels)


def line_plot(x: np.ndarray, ys: dict[str, np.ndarray], *, title: str, xlabel: str, ylabel: str,
              y_max: float = 1.0, size=(640, 420)) -> np.ndarray:
    """A minimal line chart (white background, axes, ticks, legend)."""
    w, h = size
    img = np.full((h, w, 3), 255, np.uint8)
    left, right, top, bottom = 60, w - 20, 40, h - 50

    def to_px(a, b):
        return (int(left + (a - x.min()) / (x.max() - x.min()) * (right - left)),
                int(bottom - b / y_max * (bottom - top)))

    cv2.rectangle(img, (left, top), (right, bottom), BLACK, 1)
    for k in range(6):
        yv = y_max * k / 5
        cv2.putText(img, f"{yv:.1f}", (12, to_px(x.min(), yv)[1] + 4), FONT, 0.4, BLACK, 1, cv2.LINE_AA)
        cv2.line(img, (left, to_px(x.min(), yv)[1]), (right, to_px(x.min(), yv)[1]), (225, 225, 225), 1)
    for xv in np.linspace(x.min(), x.max(), 5):
        cv2.putText(img, f"{xv:g}", (to_px(xv, 0)[0] - 8, bottom + 18), FONT, 0.4, BLACK, 1, cv2.LINE_AA)
    for k, (label, y) in enumerate(ys.items()):
        colour = _colour(k, len(ys) + 1)
        pts = np.array([to_px(a, b) for a, b in zip(x, y)], np.int32)
        cv2.polylines(img, [pts], False, colour, 2, cv2.LINE_AA)
        cv2.putText(img, label, (left + 10, top + 20 + 18 * k), FONT, 0.45, colour, 1, cv2.LINE_AA)
    cv2.putText(img, title, (left, 25), FONT, 0.55, BLACK, 1, cv2.LINE_AA)
    cv2.putText(img, xlabel, ((left + right) // 2 - 40, h - 12), FONT, 0.45, BLACK, 1, cv2.LINE_AA)
    cv2.putText(img, ylabel, (4, top - 10), FONT, 0.45, BLACK, 1, cv2.LINE_AA)
    return img


def bar_chart(values: dict[str, float], *, title: str, unit: str, size=(640, 420)) -> np.ndarray:
    """Horizontal bars, one per key."""
    w, h = size
    img = np.full((h, w, 3), 255, np.uint8)
    left, right, top = 130, w - 70, 40
    row = (h - top - 20) / max(len(values), 1)
    top_value = max([v for v in values.values() if np.isfinite(v)] + [1e-9])
    for k, (name, v) in enumerate(values.items()):
        y = int(top + k * row)
        cv2.putText(img, name, (8, y + int(row * 0.6)), FONT, 0.42, BLACK, 1, cv2.LINE_AA)
        if np.isfinite(v):
            x = int(left + v / top_value * (right - left))
            cv2.rectangle(img, (left, y + 3), (x, y + int(row) - 3), _colour(k, len(values)), -1)
            cv2.putText(img, f"{v:.1f} {unit}", (x + 4, y + int(row * 0.6)), FONT, 0.4, BLACK, 1, cv2.LINE_AA)
    cv2.putText(img, title, (8, 25), FONT, 0.55, BLACK, 1, cv2.LINE_AA)
    return img


def write_png(path: Path, img: np.ndarray) -> None:
    if not cv2.imwrite(str(path), img):
        raise StorageError(f"cannot write {path}; check the folder is writable")


def figures(folder: Path, raw: xr.Dataset, reflectors: xr.Dataset, poses: xr.Dataset, result: dict) -> list[Path]:
    """Write the report's PNGs for one sequence (``raw``, its 2D reflectors and poses) and the overall figures."""
    folder.mkdir(parents=True, exist_ok=True)
    names = [str(n) for n in reflectors["reflector"].values]
    frame = int(raw.sizes["frame"] // 2)
    views = []
    for view in raw["view"].values:
        est = reflectors.sel(view=view).isel(frame=frame)
        gt = raw.sel(view=view).isel(frame=frame)
        uv = np.where(gt["gt_visible"].values[:, None], gt["gt_reflectors2d"].values, np.nan)
        views.append(overlay(gt["ir"].values, np.stack([est["x"].values, est["y"].values], 1), uv, names,
                             f"{view}, frame {frame}", est["recovered"].values if "recovered" in est else None))
    out = [folder / "reflectors.png", folder / "skeleton.png", folder / "pck.png", folder / "joint_errors.png"]
    write_png(out[0], np.hstack(views))
    picks = np.linspace(0, poses.sizes["frame"] - 1, 4).round().astype(int)
    write_png(out[1], np.vstack([skeleton_panel(poses["position"].values[i], raw["gt_joints"].values[i],
                                                f"frame {i}") for i in picks]))
    p = result["poses"]
    curve_x = np.array(list(p["curve"]), float)
    curves = {"all joints": np.array(list(p["curve"].values()))}
    curves.update({name: np.array(list(e["curve"].values())) for name, e in p["per_exercise"].items()})
    write_png(out[2], line_plot(curve_x, curves, title="3D PCK of the Table 8 joints", xlabel="threshold (cm)",
                                ylabel="fraction"))
    write_png(out[3], bar_chart({n: j["mae_cm"] for n, j in p["per_joint"].items()}, title="mean 3D error per joint",
                                unit="cm"))
    return out


def write_html(path: Path, *, title: str, summary: dict, table: str, images: list[Path], files: list[Path]) -> None:
    rows = "".join(f"<tr><td>{html.escape(str(k))}</td><td>{html.escape(_fmt(v))}</td></tr>" for k, v in summary.items())
    imgs = "".join(f'<figure><img src="{html.escape(_link(i, path.parent))}">'
                   f"<figcaption>{html.escape(i.stem.replace('_', ' '))}</figcaption></figure>" for i in images)
    links = "".join(f'<li><a href="{html.escape(_link(f, path.parent))}">{html.escape(f.name)}</a></li>' for f in files)
    path.write_text(
        f"<!doctype html><html><head><meta charset='utf-8'><title>{html.escape(title)}</title>"
        "<style>body{font-family:sans-serif;margin:2em}img{max-width:100%}td{padding:2px 12px}"
        "pre{background:#f4f4f4;padding:1em;overflow:auto}</style></head><body>"
        f"<h1>{html.escape(title)}</h1><table>{rows}</table>{imgs}<h2>Accuracy</h2><pre>{html.escape(table)}</pre>"
        f"<h2>Files</h2><ul>{links}</ul></body></html>\n")


def _link(target: Path, page_folder: Path) -> str:
    """``target`` relative to the page's folder, as a URL path."""
    return Path(os.path.relpath(target, page_folder)).as_posix()


def _fmt(v) -> str:
    return f"{v:.4g}" if isinstance(v, float) else str(v)

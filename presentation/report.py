"""`mocapflow report`: one HTML page of a computed run, its PNG figures drawn with OpenCV.

The page shows the run's summary and, where the recordings carry ground truth, the evaluation's tables; per
sequence the marker table, the trajectories and the worst markers against the truth; the interactive 3D view; and
the figures each system's report section adds (registry.ReportSection). The drawing helpers here (line plots, bar
charts, the page) are the systems' too.
"""

from __future__ import annotations

import html
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Mapping

import cv2
import numpy as np

from mocapflow.pipeline import registry
from mocapflow.pipeline.errors import PlanError, StorageError
from mocapflow.pipeline.evaluate import evaluate
from mocapflow.presentation import viewer
from mocapflow.presentation.evaluate import headline, table
from mocapflow.tasks.shared.marker_errors import GROSS_MM, marker_errors, marker_tails, worst_markers

WHITE, GREY, BLACK = (255, 255, 255), (150, 150, 150), (0, 0, 0)
SOLVED = (80, 200, 255)  # BGR orange
TRUTH = (255, 210, 140)  # BGR light blue
BAR = (180, 119, 31)  # BGR blue: one colour for every bar, the length carries the value
# A categorical palette (Tableau 20, BGR): neighbouring entries differ, unlike a rainbow's
PALETTE = [(180, 119, 31), (14, 127, 255), (44, 160, 44), (40, 39, 214), (189, 103, 148), (75, 86, 140),
           (194, 119, 227), (127, 127, 127), (34, 189, 188), (207, 190, 23), (232, 199, 174), (120, 187, 255),
           (138, 223, 152), (150, 152, 255), (213, 176, 197), (148, 156, 196), (210, 182, 247), (199, 199, 199),
           (141, 219, 219), (229, 218, 158)]
FONT = cv2.FONT_HERSHEY_SIMPLEX


def colour(i: int, n: int) -> tuple[int, int, int]:
    hsv = np.uint8([[[int(180 * i / max(n, 1)), 220, 255]]])
    return tuple(int(c) for c in cv2.cvtColor(hsv, cv2.COLOR_HSV2BGR)[0, 0])


def line_plot(x: np.ndarray, ys: dict[str, np.ndarray], *, title: str, xlabel: str, ylabel: str,
              y_max: float = 1.0, size=(640, 420), y_min: float = 0.0, log: bool = False,
              marks: dict[str, float] | None = None) -> np.ndarray:
    """A minimal line chart (white background, axes, ticks, legend); a NaN breaks its line. ``log``: a
    logarithmic y axis from ``y_min`` (> 0) with a tick per decade, values clipped to the axes; ``marks``:
    labelled horizontal reference lines."""
    w, h = size
    img = np.full((h, w, 3), 255, np.uint8)
    left, right, top, bottom = 60, w - 180, 40, h - 50  # the legend sits right of the axes, off the curves
    lo, hi = (np.log10(y_min), np.log10(y_max)) if log else (y_min, y_max)

    def to_px(a, b):
        v = np.log10(np.clip(b, y_min, y_max)) if log else b
        return (int(left + (a - x.min()) / (x.max() - x.min()) * (right - left)),
                int(bottom - (v - lo) / (hi - lo) * (bottom - top)))

    cv2.rectangle(img, (left, top), (right, bottom), BLACK, 1)
    ticks = 10.0 ** np.arange(np.ceil(lo), np.floor(hi) + 1) if log else y_min + (y_max - y_min) * np.arange(6) / 5
    for yv in ticks:
        cv2.putText(img, f"{yv:g}", (12, to_px(x.min(), yv)[1] + 4), FONT, 0.4, BLACK, 1, cv2.LINE_AA)
        cv2.line(img, (left, to_px(x.min(), yv)[1]), (right, to_px(x.min(), yv)[1]), (225, 225, 225), 1)
    for label, yv in (marks or {}).items():
        py = to_px(x.min(), yv)[1]
        for a in range(left, right, 12):  # dashed
            cv2.line(img, (a, py), (min(a + 6, right), py), GREY, 1)
        cv2.putText(img, label, (right - 8 - 8 * len(label), py - 5), FONT, 0.4, GREY, 1, cv2.LINE_AA)
    digits = max(0, 2 - int(np.floor(np.log10(max(x.max() - x.min(), 1e-9)))))  # 3 significant over the span
    for xv in np.linspace(x.min(), x.max(), 5):
        cv2.putText(img, f"{round(float(xv), digits):g}", (to_px(xv, y_max)[0] - 8, bottom + 18), FONT, 0.4, BLACK,
                    1, cv2.LINE_AA)
    for k, (label, y) in enumerate(ys.items()):
        colour = PALETTE[k % len(PALETTE)]
        ok = np.flatnonzero(np.isfinite(y))
        for run in np.split(ok, np.flatnonzero(np.diff(ok) > 1) + 1):
            if run.size:  # a single point drawn as a dot
                pts = np.array([to_px(x[i], y[i]) for i in run], np.int32)
                cv2.polylines(img, [pts], False, colour, 2, cv2.LINE_AA)
        cv2.line(img, (right + 12, top + 10 + 18 * k), (right + 32, top + 10 + 18 * k), colour, 2, cv2.LINE_AA)
        cv2.putText(img, label[:20], (right + 38, top + 14 + 18 * k), FONT, 0.42, BLACK, 1, cv2.LINE_AA)
    cv2.putText(img, title, (left, 16), FONT, 0.55, BLACK, 1, cv2.LINE_AA)
    cv2.putText(img, xlabel, ((left + right) // 2 - 40, h - 12), FONT, 0.45, BLACK, 1, cv2.LINE_AA)
    cv2.putText(img, ylabel, (4, top - 8), FONT, 0.45, BLACK, 1, cv2.LINE_AA)
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
            cv2.rectangle(img, (left, y + 3), (x, y + int(row) - 3), BAR, -1)
            cv2.putText(img, f"{v:.1f} {unit}", (x + 4, y + int(row * 0.6)), FONT, 0.4, BLACK, 1, cv2.LINE_AA)
    cv2.putText(img, title, (8, 25), FONT, 0.55, BLACK, 1, cv2.LINE_AA)
    return img


def write_png(path: Path, img: np.ndarray) -> None:
    if not cv2.imwrite(str(path), img):
        raise StorageError(f"cannot write {path}; check the folder is writable")


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


# ---- `mocapflow report`: any run, with or without ground truth -------------------------------------------


@dataclass
class Take:
    """What the report shows of one sequence: its markers (and where they come from), the fused views' evidence,
    the solved joints, and the ground truth where the recording has it."""

    id: str
    fps: float
    label: str
    stage: str
    names: list[str]
    position: np.ndarray  # (frame, marker, 3) m, NaN where missing
    views: np.ndarray | None = None  # (frame, marker) views fused
    residual: np.ndarray | None = None  # (frame, marker) m, mean distance of the views' estimates from the fused
    # point, NaN where fewer than two views saw the marker
    joints: np.ndarray | None = None  # (frame, joint, 3) m
    joint_names: list[str] = field(default_factory=list)
    parents: list[int] = field(default_factory=list)
    gt_joints: np.ndarray | None = None  # (frame, joint, 3) m
    gt_markers: np.ndarray | None = None  # (frame, marker, 3) m, the true position of each of ``names``
    note: str = ""  # shown under the sequence's heading (e.g. that ``names`` is a subsample of the take's points)


def gaps(present: np.ndarray) -> list[tuple[int, int]]:
    """(first frame, length) of each run of missing frames.  (frame,) bool"""
    missing = np.concatenate([[False], ~present, [False]]).astype(np.int8)
    starts, stops = np.flatnonzero(np.diff(missing) == 1), np.flatnonzero(np.diff(missing) == -1)
    return [(int(a), int(b - a)) for a, b in zip(starts, stops)]


def marker_rows(take: Take) -> list[dict]:
    """Per marker: frames tracked (%), gaps (count, longest in frames and seconds), the median residual (mm: the
    mean distance of the views' estimates from the fused point, in frames seen by two views or more) and the mean
    number of views where tracked."""
    rows = []
    present = np.isfinite(take.position).all(axis=-1)  # (frame, marker)
    for m, name in enumerate(take.names):
        runs = gaps(present[:, m])
        longest = max((n for _, n in runs), default=0)
        row = {"marker": name, "tracked %": round(100.0 * present[:, m].mean(), 1), "gaps": len(runs),
               "longest gap (frames)": longest, "longest gap (s)": round(longest / take.fps, 3)}
        if take.residual is not None:
            r = take.residual[:, m][np.isfinite(take.residual[:, m])]
            row["median residual (mm)"] = round(1000.0 * float(np.median(r)), 1) if r.size else float("nan")
        if take.views is not None:
            seen = take.views[:, m][take.views[:, m] > 0]
            row["views (mean)"] = round(float(seen.mean()), 2) if seen.size else 0.0
        rows.append(row)
    return rows


LEGEND_MAX = 40  # markers named in the trajectories' legend; above it the legend gives their count
TABLE_OPEN_MAX = 40  # marker-table rows shown open; a longer table is folded (<details>)


def trajectories_plot(take: Take, size=(980, 600)) -> np.ndarray:
    """x, y and z of every marker over time (s), one panel each, a legend of the markers on the right."""
    w, h = size
    img = np.full((h, w, 3), 255, np.uint8)
    left, right, legend_x = 70, w - 200, w - 185
    t = np.arange(take.position.shape[0]) / take.fps
    panel_h = (h - 60) // 3
    for axis, label in enumerate("xyz"):
        top = 30 + axis * panel_h
        bottom = top + panel_h - 25
        values = take.position[..., axis]
        lo, hi = (np.nanmin(values), np.nanmax(values)) if np.isfinite(values).any() else (0.0, 1.0)
        hi = hi if hi > lo else lo + 1e-3
        cv2.rectangle(img, (left, top), (right, bottom), BLACK, 1)
        for v in (lo, hi):
            py = int(bottom - (v - lo) / (hi - lo) * (bottom - top))
            cv2.putText(img, f"{v:.2f}", (8, py + 4), FONT, 0.38, BLACK, 1, cv2.LINE_AA)
        cv2.putText(img, f"{label} (m)", (8, (top + bottom) // 2 + 4), FONT, 0.45, BLACK, 1, cv2.LINE_AA)
        for m in range(len(take.names)):
            xs = left + (t / max(t[-1], 1e-9)) * (right - left)
            ys = bottom - (values[:, m] - lo) / (hi - lo) * (bottom - top)
            ok = np.isfinite(ys)
            for run in np.split(np.flatnonzero(ok), np.flatnonzero(np.diff(np.flatnonzero(ok)) > 1) + 1):
                if run.size > 1:  # a gap breaks the line
                    pts = np.stack([xs[run], ys[run]], 1).astype(np.int32)
                    cv2.polylines(img, [pts], False, PALETTE[m % len(PALETTE)], 1, cv2.LINE_AA)
    cv2.putText(img, f"{take.id}: marker trajectories ({take.stage})", (left, 20), FONT, 0.5, BLACK, 1, cv2.LINE_AA)
    cv2.putText(img, f"0 - {t[-1]:.2f} s", (left, h - 12), FONT, 0.42, BLACK, 1, cv2.LINE_AA)
    if len(take.names) > LEGEND_MAX:  # too many names to read: the count instead
        cv2.putText(img, f"{len(take.names)} markers", (legend_x, 35), FONT, 0.45, BLACK, 1, cv2.LINE_AA)
        return img
    row = min(18, (h - 40) // max(len(take.names), 1))
    for m, name in enumerate(take.names):
        y = 35 + m * row
        cv2.line(img, (legend_x, y - 4), (legend_x + 18, y - 4), PALETTE[m % len(PALETTE)], 2, cv2.LINE_AA)
        cv2.putText(img, name[:22], (legend_x + 24, y), FONT, min(0.4, row / 40), BLACK, 1, cv2.LINE_AA)
    return img


WORST_K = 5  # markers shown in the worst-markers table and plot


def worst_rows(take: Take, k: int = WORST_K) -> tuple[np.ndarray, list[dict]]:
    """The ``k`` markers farthest from the ground truth (by p95, ties by the largest error): their error over
    time (frame, k) mm and per marker the largest error and its frame, p95 and the frames more than 10 cm off
    (count and share of the frames with a value)."""
    errors = marker_errors(take.position, take.gt_markers)  # (frame, marker) mm, NaN where untracked
    tails, worst = marker_tails(errors), worst_markers(errors, k)
    rows = [{"marker": take.names[m], "max (mm)": round(float(tails["max_mm"][m]), 1),
             "at frame": int(tails["max_frame"][m]) if tails["max_frame"][m] >= 0 else float("nan"),
             "at (s)": round(float(tails["max_frame"][m]) / take.fps, 3) if tails["max_frame"][m] >= 0 else float("nan"),
             "p95 (mm)": round(float(tails["p95_mm"][m]), 1),
             f"> {GROSS_MM / 10:g} cm (frames)": int(tails["gross_frames"][m]),
             f"> {GROSS_MM / 10:g} cm (%)": round(100.0 * float(tails["gross_share"][m]), 1)} for m in worst]
    return errors[:, worst], rows


def worst_markers_plot(take: Take, errors: np.ndarray, names: list[str], size=(980, 420)) -> np.ndarray:
    """The worst markers' error against the ground truth over time (s), log scale, the 10 cm line dashed.
    (frame, k) mm"""
    t = np.arange(errors.shape[0]) / take.fps
    top = float(np.nanmax(errors)) if np.isfinite(errors).any() else GROSS_MM
    y_max = 10.0 ** np.ceil(np.log10(max(top, 2 * GROSS_MM)))  # a decade above the worst, the 10 cm line inside
    return line_plot(t if t.size > 1 else np.array([0.0, 1.0]), dict(zip(names, errors.T)),
                     title=f"{take.id}: the {len(names)} worst markers against ground truth ({take.stage})",
                     xlabel="time (s)", ylabel="error (mm)", y_min=1.0, y_max=y_max, log=True,
                     marks={f"{GROSS_MM / 10:g} cm": GROSS_MM}, size=size)


def viewer_sequence(t: Take) -> dict:
    """One sequence of the 3D view: its markers, skeleton and ground-truth skeleton per frame (mm), drawn truth
    first, the markers on top."""
    layers, legend = [], []
    if t.gt_joints is not None:
        layers.append(viewer.skeleton("gt_joint_xyz", viewer.TRUTH, 1.5, viewer.TRUTH_DASH))
    if t.joints is not None:
        layers.append(viewer.skeleton("joint_xyz", viewer.SOLVED, 3))
        legend.append(viewer.entry("solved skeleton", viewer.SOLVED))
    if t.gt_joints is not None:
        legend.append(viewer.entry("ground-truth skeleton (dashed)", viewer.TRUTH))
    layers.append(viewer.markers("marker_xyz", "markers"))
    return {"id": t.id, "label": t.label, "fps": t.fps, "frames": int(t.position.shape[0]), "markers": t.names,
            "marker_xyz": viewer.mm(t.position), "joints": t.joint_names, "parents": t.parents,
            "joint_xyz": viewer.mm(t.joints), "gt_joint_xyz": viewer.mm(t.gt_joints),
            "views": [viewer.view(t.id, layers, "data-painted")], "legend": legend}


def viewer_html(takes: list[Take]) -> str:
    """The self-contained 3D view of the takes (a page fragment: inline script and data, no network)."""
    return viewer.viewer_html([viewer_sequence(t) for t in takes], what="sequence", palette=PALETTE,
                              centre=("marker_xyz", "joint_xyz"))


def html_table(rows: list[dict]) -> str:
    """Rows of equal keys as an HTML table, numbers to 3 significant digits."""
    if not rows:
        return "<p>(none)</p>"
    head = "".join(f"<th>{html.escape(k)}</th>" for k in rows[0])
    body = "".join("<tr>" + "".join(f"<td>{html.escape(_cell(v))}</td>" for v in r.values()) + "</tr>" for r in rows)
    return f"<table class='grid'><tr>{head}</tr>{body}</table>"


def _cell(v) -> str:
    if isinstance(v, float):
        return f"{v:g}" if np.isfinite(v) else "-"
    return str(v)


def named_figures(figures_: dict, names: Mapping[str, tuple[str, float, str]]) -> dict[str, str]:
    """The headline figures with names and units: those ``names`` knows (JSON key -> (label, scale, unit)), in its
    order."""
    out = {}
    for key, (label, scale, unit) in names.items():
        if key in figures_ and isinstance(figures_[key], (int, float)):
            v = figures_[key] * scale
            out[label] = f"{v:.4g} {unit}".strip() if isinstance(v, float) else f"{v} {unit}".strip()
    return out


def write_report(folder: Path, takes: list[Take], *, title: str, summary: dict, accuracy: str | None,
                 images: list[Path] = (), files: list[Path] = ()) -> Path:
    """``folder/report.html``: the summary, the accuracy tables (or why there are none), per sequence the marker
    table and the trajectories, the figures, the 3D viewer and the files; every image beside it."""
    folder.mkdir(parents=True, exist_ok=True)
    sections = []
    for take in takes:
        png = folder / f"trajectories_{take.id}.png"
        write_png(png, trajectories_plot(take))
        heading = html.escape(take.id + (f" ({take.label})" if take.label and take.label != take.id else ""))
        sections.append(f"<h3 id='seq-{html.escape(take.id)}'>{heading}</h3><p>{take.position.shape[0]} frames at "
                        f"{take.fps:g} fps, {len(take.names)} markers from stage <code>{html.escape(take.stage)}</code>"
                        f"</p>{_note(take)}{_marker_table(take)}<figure><img src='{html.escape(png.name)}'>"
                        f"<figcaption>trajectories of {heading}; a gap breaks its line</figcaption></figure>"
                        + (_worst_section(folder, take, heading) if take.gt_markers is not None else ""))
    rows = "".join(f"<tr><td>{html.escape(str(k))}</td><td>{html.escape(_fmt(v))}</td></tr>" for k, v in summary.items())
    imgs = "".join(f'<figure><img src="{html.escape(_link(i, folder))}">'
                   f"<figcaption>{html.escape(i.stem.replace('_', ' '))}</figcaption></figure>" for i in images)
    links = "".join(f'<li><a href="{html.escape(_link(f, folder))}">{html.escape(f.name)}</a></li>' for f in files)
    accuracy_html = (f"<pre>{html.escape(accuracy)}</pre>" if accuracy else
                     "<p>No ground truth in these recordings: accuracy is not measured; the tables below describe "
                     "the take itself.</p>")
    page = folder / "report.html"
    page.write_text(
        f"<!doctype html><html><head><meta charset='utf-8'><title>{html.escape(title)}</title><style>"
        "body{font-family:sans-serif;margin:2em}img{max-width:100%}td,th{padding:2px 10px;text-align:right}"
        "td:first-child,th:first-child{text-align:left}"
        "table.grid{border-collapse:collapse}table.grid td,table.grid th{border-bottom:1px solid #ddd}"
        f"pre{{background:#f4f4f4;padding:1em;overflow:auto}}{viewer.STYLE}</style></head><body>"
        f"<h1>{html.escape(title)}</h1><table>{rows}</table><h2>Accuracy</h2>{accuracy_html}{imgs}"
        f"<h2>3D view</h2>{viewer_html(takes)}<h2>Markers per sequence</h2>{''.join(sections)}"
        f"<h2>Files</h2><ul>{links or '<li>(none)</li>'}</ul></body></html>\n")
    return page


def _note(take: Take) -> str:
    return f"<p><em>{html.escape(take.note)}</em></p>" if take.note else ""


def _marker_table(take: Take) -> str:
    """The marker table, folded where it is long."""
    table_ = html_table(marker_rows(take))
    if len(take.names) <= TABLE_OPEN_MAX:
        return table_
    return f"<details><summary>marker table ({len(take.names)} rows)</summary>{table_}</details>"


def _worst_section(folder: Path, take: Take, heading: str) -> str:
    """The worst markers against the ground truth: their table and ``worst_markers_{id}.png``."""
    errors, rows = worst_rows(take)
    png = folder / f"worst_markers_{take.id}.png"
    write_png(png, worst_markers_plot(take, errors, [r["marker"] for r in rows]))
    return (f"<h4>Worst markers against ground truth</h4><p>The {len(rows)} markers with the largest 95th-percentile "
            f"error (ties: the largest error); frames more than {GROSS_MM / 10:g} cm off, in % of the frames the "
            f"marker is tracked.</p>{html_table(rows)}<figure><img src='{html.escape(png.name)}'><figcaption>error of "
            f"the worst markers of {heading} over time (log scale); a gap breaks its line</figcaption></figure>")


def recordings_hold(catalog, plan, store, variable: str) -> bool:
    """Whether every sequence's recording (the catalog's source stage) holds ``variable`` (a system's ground truth:
    ReportSection.truth)."""
    source = next((s.name for s in catalog.stages.values() if s.spec.source), None)
    return source is not None and bool(plan.sequences) and all(
        variable in plan.open(store, source, seq.id).data_vars for seq in plan.sequences)


def base_takes(catalog, plan, store, stage: str) -> list[Take]:
    """Every sequence of ``plan`` as a Take of the markers ``stage`` wrote (a ``reflector`` or ``marker`` axis): their
    positions, rate and the recording's label (from the catalog's source stage, where it has one)."""
    source = next((s.name for s in catalog.stages.values() if s.spec.source), None)
    takes = []
    for seq in plan.sequences:
        markers = plan.open(store, stage, seq.id).load()
        dim = next(d for d in markers["position"].dims if d not in ("frame", "xyz"))  # the marker axis, by any name
        raw = plan.open(store, source, seq.id) if source else None
        fps = float(markers.attrs.get("fps", raw.attrs["fps"] if raw is not None else 30.0))
        takes.append(Take(seq.id, fps, str((raw.attrs if raw is not None else {}).get("exercise", "")), stage,
                          [str(n) for n in markers[dim].values], markers["position"].values.astype(np.float64)))
    return takes


def build_report(catalog, plan, store, folder: Path, *, title: str, summary: dict | None = None,
                 files: list[Path] = (), result: dict | None = None) -> tuple[Path, list[Path], dict]:
    """The report of a computed run: with ground truth, the accuracy tables and figures; always, per sequence the
    marker table, trajectories and the 3D view. ``result``: the evaluation, when already made. Returns the page,
    the images and the evaluation's figures. What it shows of each system comes from that system's report sections
    (registry.ReportSection): the takes from the first that has some, the figures and figure names from all (the
    figures with or without an evaluation: ``{}`` where there is none)."""
    sections = [r for r in registry.report_sections() if r.applies(catalog)]
    takes = next((found for r in sections if r.takes is not None and (found := r.takes(catalog, plan, store))), [])
    if not takes:
        names = [r.name for r in registry.report_sections()]
        raise PlanError(f"the catalog has no stage that a system's report section shows (sections: {names}); add "
                        "a stage writing markers (see catalog.yaml)")
    images, accuracy, figures_ = [], None, {}
    if result is None:
        truth = any(r.truth is not None and recordings_hold(catalog, plan, store, r.truth) for r in sections)
        try:  # without truth, what a system checks of a take by itself (DeepMoCap's per-view plausibility)
            result = evaluate(catalog, plan, store, thorough=False)  # the slowest figures (scene flow) left out
        except PlanError as exc:  # no stage the evaluation scores (or, without truth, nothing to check): say so
            accuracy = f"not measured: {exc}" if truth else None
    if result is not None:
        accuracy, figures_ = table(result), headline(result)
    images = [p for r in sections if r.figures is not None for p in r.figures(folder, catalog, plan, store, result or {})]
    known = {"sequences": ("sequences", 1, "")}
    for r in sections:
        known.update(r.named_figures)
    named = {"sequences": len(takes), "frames": sum(t.position.shape[0] for t in takes),
             **named_figures(figures_, known), **(summary or {})}
    page = write_report(folder, takes, title=title, summary=named, accuracy=accuracy, images=images, files=files)
    return page, images + [folder / f"{kind}_{t.id}.png" for t in takes for kind in ("trajectories", "worst_markers")
                           if kind == "trajectories" or t.gt_markers is not None], figures_

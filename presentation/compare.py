"""`mocapflow compare`'s output (pipeline/compare.py scores the systems): the text table, the ``--json`` figures and
the page (``--out``).

The page: a table of the figures per system, then the 3D view (presentation/viewer.py): one canvas per system, all
on the same instant of the same take, each with that system's joints (orange) and surface (blue dots, where it
gives one) against the true skeleton (dashed white), or every system's joints overlaid in its own colour; one
slider, one play button. Below, per take the error over time (MPJPE per matched frame, one line per system) and over
all takes the MPJPE per body part (grouped bars). Self-contained: inline script and data, no network. Once drawn the
page's body carries ``data-take``, ``data-frames`` and per system ``data-painted-<system>`` (its canvas's pixels
drawn over the background), so a headless browser can tell it ran.
"""

from __future__ import annotations

import html
from pathlib import Path

import cv2
import numpy as np

from mocapflow.presentation import viewer
from mocapflow.presentation.evaluate import format_rows
from mocapflow.presentation.report import BLACK, FONT, PALETTE, html_table, line_plot, write_png


def viewer_sequence(take: str, t: dict) -> dict:
    """One take of the 3D view: the instants compared, the truth and per system its joints, surface and per-frame
    error; a view per system."""
    times = [round(float(x), 4) for x in t["times"]]
    step = float(np.median(np.diff(t["times"]))) if len(times) > 1 else 0.0
    seq = {"id": take, "fps": 1.0 / step if step > 0 else 10.0, "frames": len(times), "times": times,
           "parents": [int(p) for p in t["skeleton"].parents], "truth": viewer.mm(t["truth"])}
    views, surfaces = [], False
    for k, (name, r) in enumerate(t["systems"].items()):
        seq[f"joints_{k}"], seq[f"surface_{k}"] = viewer.mm(r["joints"]), viewer.mm(r["surface"])
        seq[f"error_{k}"] = [None if not np.isfinite(e) else round(float(e), 1) for e in r["mpjpe_per_frame_mm"]]
        surfaces |= r["surface"] is not None
        layers = [viewer.points(f"surface_{k}", viewer.SURFACE, 1.8, tint=True, overlay=False),
                  viewer.skeleton("truth", viewer.TRUTH, 1.5, viewer.TRUTH_DASH),
                  viewer.skeleton(f"joints_{k}", viewer.SOLVED, 3, tint=True),
                  viewer.points(f"joints_{k}", viewer.SOLVED, 3, tint=True)]
        views.append(viewer.view(name, layers, f"data-painted-{name}",
                                 {"values": f"error_{k}", "unit": "mm MPJPE", "missing": "no joints"}))
    seq["views"] = views
    seq["legend"] = [viewer.entry("the system's joints", viewer.SOLVED, tint=True),
                     *([viewer.entry("its surface", viewer.SURFACE, "dot", tint=True)] if surfaces else []),
                     viewer.entry("the truth (dashed)", viewer.TRUTH)]
    return seq


def part_chart(result: dict, size=(900, 460)) -> np.ndarray:
    """MPJPE per body part over every take, one bar per system in each part's group."""
    w, h = size
    img = np.full((h, w, 3), 255, np.uint8)
    systems, parts = result["systems"], list(result["skeleton"].parts)
    left, right, top, bottom = 60, w - 20, 60, h - 60
    values = np.array([[result["overall"][s]["parts_mm"][p] for s in systems] for p in parts], float)
    top_value = float(np.nanmax(values)) if np.isfinite(values).any() else 1.0
    step = 10 ** np.floor(np.log10(max(top_value, 1e-9)))
    y_max = float(np.ceil(top_value / step) * step)
    cv2.rectangle(img, (left, top), (right, bottom), BLACK, 1)
    for k in range(6):
        v = y_max * k / 5
        y = int(bottom - v / y_max * (bottom - top))
        cv2.line(img, (left, y), (right, y), (225, 225, 225), 1)
        cv2.putText(img, f"{v:g}", (8, y + 4), FONT, 0.4, BLACK, 1, cv2.LINE_AA)
    group = (right - left) / len(parts)
    bar = group * 0.8 / len(systems)
    for g, part in enumerate(parts):
        x0 = left + g * group + group * 0.1
        for k in range(len(systems)):
            v = values[g, k]
            if not np.isfinite(v):
                continue
            x = int(x0 + k * bar)
            y = int(bottom - v / y_max * (bottom - top))
            cv2.rectangle(img, (x, y), (int(x + bar) - 2, bottom), PALETTE[k % len(PALETTE)], -1)
            cv2.putText(img, f"{v:.0f}", (x, y - 4), FONT, 0.36, BLACK, 1, cv2.LINE_AA)
        cv2.putText(img, part, (int(x0), bottom + 18), FONT, 0.42, BLACK, 1, cv2.LINE_AA)
    for k, s in enumerate(systems):
        cv2.rectangle(img, (left + 160 * k, 30), (left + 160 * k + 14, 44), PALETTE[k % len(PALETTE)], -1)
        cv2.putText(img, s, (left + 160 * k + 20, 42), FONT, 0.45, BLACK, 1, cv2.LINE_AA)
    cv2.putText(img, "MPJPE per body part over every take (mm)", (left, 18), FONT, 0.55, BLACK, 1, cv2.LINE_AA)
    cv2.putText(img, "error (mm)", (4, top - 6), FONT, 0.4, BLACK, 1, cv2.LINE_AA)
    return img


def error_plot(take: str, t: dict) -> np.ndarray:
    """MPJPE per matched frame of one take, one line per system."""
    ys = {s: r["mpjpe_per_frame_mm"] for s, r in t["systems"].items()}
    top = max([float(np.nanmax(y)) for y in ys.values() if np.isfinite(y).any()] + [10.0])
    x = t["times"] if len(t["times"]) > 1 else np.array([0.0, 1.0])
    return line_plot(x, ys, title=f"{take}: MPJPE per frame (same truth frames)", xlabel="time (s)",
                     ylabel="MPJPE (mm)", y_max=float(np.ceil(top / 20) * 20), size=(900, 380))


def _rows(result: dict) -> list[dict]:
    rows = []
    for s in result["systems"]:
        o = result["overall"][s]
        rows.append({"system": s, "takes": o["takes"], "frames": o["frames"], "MPJPE (mm)": round(o["mpjpe_mm"], 1),
                     "take median / p90 (mm)": f"{o['take_median_mm']:.1f} / {o['take_p90_mm']:.1f}",
                     "surface (mm)": "-" if o["surface_mm"] is None else round(o["surface_mm"], 1),
                     "complete (%)": round(100 * o["completeness"], 1),
                     "CPU s per captured s": round(o["cpu_s_per_s"], 1),
                     **{k: v for k, v in o["needs"].items()}})
    return rows


def write_compare_page(folder: Path, result: dict, *, title: str) -> list[Path]:
    """``folder/compare.html`` and its figures; returns the figures, then the page."""
    folder.mkdir(parents=True, exist_ok=True)
    images = []
    parts = folder / "compare_parts.png"
    write_png(parts, part_chart(result))
    images.append(parts)
    for take, t in result["takes"].items():
        path = folder / f"compare_error_{take}.png"
        write_png(path, error_plot(take, t))
        images.append(path)
    per_take = [{"take": take, "frames compared": len(t["times"]),
                 **{f"{s} MPJPE (mm)": round(t["systems"][s]["mpjpe_mm"], 1) for s in result["systems"]},
                 **{f"{s} surface (mm)": round(t["systems"][s]["surface_mm"], 1) for s in result["systems"]
                    if t["systems"][s]["surface_mm"] is not None}} for take, t in result["takes"].items()]
    figures = "".join(f"<figure><img src='{html.escape(p.name)}'><figcaption>{html.escape(p.stem.replace('_', ' '))}"
                      "</figcaption></figure>" for p in images)
    view = viewer.viewer_html([viewer_sequence(take, t) for take, t in result["takes"].items()], what="take",
                              palette=PALETTE, size=(420, 480), span_mm=2300.0, centre=("truth",), overlay=True)
    page = folder / "compare.html"
    page.write_text(
        f"<!doctype html><html><head><meta charset='utf-8'><title>{html.escape(title)}</title><style>"
        "body{font-family:sans-serif;margin:2em}img{max-width:100%}td,th{padding:2px 10px;text-align:right}"
        "td:first-child,th:first-child{text-align:left}table.grid{border-collapse:collapse}"
        "table.grid td,table.grid th{border-bottom:1px solid #ddd}"
        f"{viewer.STYLE}</style></head><body><h1>{html.escape(title)}</h1>"
        "<p>One performance filmed by every system from the same posed mesh; each scored on the same truth frames "
        "(the instants every system filmed).</p>"
        f"<h2>Per system</h2>{html_table(_rows(result))}"
        f"<h2>Side by side</h2>{view}"
        f"<h2>Error over time and per body part</h2>{figures}<h2>Per take</h2>{html_table(per_take)}"
        "</body></html>\n")
    return images + [page]


def headline(result: dict) -> dict:
    """`mocapflow compare --json`: per system its MPJPE, cost, completeness and surface error."""
    out: dict = {"compare_takes": len(result["takes"]), "compare_frames": sum(len(t["times"])
                                                                           for t in result["takes"].values())}
    for system, o in result["overall"].items():
        out[f"compare_{system}_mpjpe_mm"] = o["mpjpe_mm"]
        out[f"compare_{system}_take_median_mm"] = o["take_median_mm"]
        out[f"compare_{system}_cpu_s_per_s"] = o["cpu_s_per_s"]
        out[f"compare_{system}_completeness"] = o["completeness"]
        if o["surface_mm"] is not None:
            out[f"compare_{system}_surface_mm"] = o["surface_mm"]
    return out


def _num(v, fmt="{:.1f}") -> str:
    return "-" if v is None or not np.isfinite(v) else fmt.format(v)


def table(result: dict) -> str:
    """The comparison as text: one row per system, then per take, then what each needs."""
    systems, parts = result["systems"], list(result["skeleton"].parts)
    rows = [("system", "MPJPE mm", "takes median / p90", *parts, "surface mm", "complete", "CPU s / s")]
    for s in systems:
        o = result["overall"][s]
        rows.append((s, _num(o["mpjpe_mm"]), f"{_num(o['take_median_mm'])} / {_num(o['take_p90_mm'])}",
                     *(_num(o["parts_mm"][p]) for p in parts), _num(o["surface_mm"]),
                     f"{o['completeness']:.1%}", _num(o["cpu_s_per_s"])))
    per_take = [("take", "frames", "truth gap mm", *(f"{s} MPJPE mm" for s in systems))]
    for take, t in result["takes"].items():
        per_take.append((take, str(len(t["times"])), _num(t["truth_gap_mm"]),
                         *(_num(t["systems"][s]["mpjpe_mm"]) for s in systems)))
    needs = [f"{s}: " + "; ".join(f"{k} {v}" for k, v in result["overall"][s]["needs"].items()) for s in systems]
    return "\n".join(format_rows(rows) + [""] + format_rows(per_take) + ["", "what each needs"] + needs)

"""The comparison's page (`mocapflow compare --out`): the systems side by side over the same frames.

A table of the figures per system, then the 3D view: one canvas per system, all on the same instant of the same
take, each with that system's joints (orange) and surface (blue dots, where it gives one) against the true
skeleton (dashed white); one slider, one play button. Below, per take the error over time (MPJPE per matched
frame, one line per system) and over all takes the MPJPE per body part (grouped bars). Self-contained: inline script
and data, no network. Once drawn the page's body carries ``data-take``, ``data-frames`` and per system
``data-painted-<system>`` (its canvas's pixels drawn over the background), so a headless browser can tell it ran.
"""

from __future__ import annotations

import html
import json
from pathlib import Path

import cv2
import numpy as np

from mocapflow.pipeline.compare import BODY_PARTS
from mocapflow.pipeline.report import BLACK, FONT, PALETTE, html_table, line_plot, write_png
from mocapflow.tasks.shared.body import JOINT_NAMES, PARENTS


def _mm(a) -> list | None:
    """(frame, point, 3) m -> nested lists of integer mm, None where missing."""
    if a is None:
        return None
    return [[None if not np.isfinite(p).all() else [round(float(c) * 1000) for c in p] for p in f] for f in a]


def viewer_data(result: dict) -> dict:
    """Per take the instants compared, the truth and per system its joints, surface and per-frame error."""
    takes = []
    for take, t in result["takes"].items():
        takes.append({"id": take, "times": [round(float(x), 4) for x in t["times"]], "truth": _mm(t["truth"]),
                      "systems": [{"name": s, "joints": _mm(r["joints"]), "surface": _mm(r["surface"]),
                                   "error": [None if not np.isfinite(e) else round(float(e), 1)
                                             for e in r["mpjpe_per_frame_mm"]]}
                                  for s, r in t["systems"].items()]})
    return {"takes": takes, "parents": [int(p) for p in PARENTS], "joints": list(JOINT_NAMES)}


def part_chart(result: dict, size=(900, 460)) -> np.ndarray:
    """MPJPE per body part over every take, one bar per system in each part's group."""
    w, h = size
    img = np.full((h, w, 3), 255, np.uint8)
    systems = result["systems"]
    left, right, top, bottom = 60, w - 20, 60, h - 60
    values = np.array([[result["overall"][s]["parts_mm"][p] for s in systems] for p in BODY_PARTS], float)
    top_value = float(np.nanmax(values)) if np.isfinite(values).any() else 1.0
    step = 10 ** np.floor(np.log10(max(top_value, 1e-9)))
    y_max = float(np.ceil(top_value / step) * step)
    cv2.rectangle(img, (left, top), (right, bottom), BLACK, 1)
    for k in range(6):
        v = y_max * k / 5
        y = int(bottom - v / y_max * (bottom - top))
        cv2.line(img, (left, y), (right, y), (225, 225, 225), 1)
        cv2.putText(img, f"{v:g}", (8, y + 4), FONT, 0.4, BLACK, 1, cv2.LINE_AA)
    group = (right - left) / len(BODY_PARTS)
    bar = group * 0.8 / len(systems)
    for g, part in enumerate(BODY_PARTS):
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
    data = json.dumps(viewer_data(result), separators=(",", ":")).replace("</", "<\\/")
    page = folder / "compare.html"
    page.write_text(
        f"<!doctype html><html><head><meta charset='utf-8'><title>{html.escape(title)}</title><style>"
        "body{font-family:sans-serif;margin:2em}img{max-width:100%}td,th{padding:2px 10px;text-align:right}"
        "td:first-child,th:first-child{text-align:left}table.grid{border-collapse:collapse}"
        "table.grid td,table.grid th{border-bottom:1px solid #ddd}"
        "#cmp-views{display:flex;gap:.6em;flex-wrap:wrap}#cmp-views figure{margin:0}"
        "#cmp-views canvas{background:#1e1e1e;border-radius:4px;cursor:grab}#cmp-controls>*{margin-right:.6em}"
        f"</style></head><body><h1>{html.escape(title)}</h1>"
        "<p>One performance filmed by every system from the same posed mesh; each scored on the same truth frames "
        "(the instants every system filmed).</p>"
        f"<h2>Per system</h2>{html_table(_rows(result))}"
        "<h2>Side by side</h2><div id='cmp-controls'><label>take <select id='cmp-take'></select></label>"
        "<button id='cmp-play'>play</button><input id='cmp-frame' type='range' min='0' value='0' style='width:320px'>"
        "<span id='cmp-label'></span></div><div id='cmp-views'></div>"
        "<p><span style='color:#e08020'>&#9632;</span> the system's joints &nbsp; <span style='color:#4a90d9'>&#9679;"
        "</span> its surface &nbsp; dashed: the truth</p>"
        f"<h2>Error over time and per body part</h2>{figures}<h2>Per take</h2>{html_table(per_take)}"
        f"<script>var DATA = {data};\n{SCRIPT}</script></body></html>\n")
    return images + [page]


SCRIPT = r"""
(function () {
  "use strict";
  var BG = [30, 30, 30], SOLVED = "#ffa040", TRUTH = "#f0f0f0", SURFACE = "#4a90d9";
  var views = document.getElementById("cmp-views"), select = document.getElementById("cmp-take");
  var slider = document.getElementById("cmp-frame"), label = document.getElementById("cmp-label");
  var play = document.getElementById("cmp-play");
  var state = {take: 0, frame: 0, az: -0.9, el: 0.3, playing: false, last: 0}, canvases = [];

  function centre(take) {  // the truth's mean (mm): every view turns about the same point
    var s = [0, 0, 0], n = 0;
    take.truth.forEach(function (f) { f.forEach(function (p) { if (p) { s[0] += p[0]; s[1] += p[1]; s[2] += p[2]; n++; } }); });
    return n ? [s[0] / n, s[1] / n, s[2] / n] : [0, 0, 0];
  }
  function project(cv, p, c) {
    var x = p[0] - c[0], y = p[1] - c[1], z = p[2] - c[2];
    var ca = Math.cos(state.az), sa = Math.sin(state.az), ce = Math.cos(state.el), se = Math.sin(state.el);
    var xr = ca * x - sa * y, yr = sa * x + ca * y, s = cv.height / 2300;
    return [cv.width / 2 + xr * s, cv.height / 2 - (ce * z - se * yr) * s];
  }
  function line(ctx, a, b, colour, width, dash) {
    ctx.strokeStyle = colour; ctx.lineWidth = width; ctx.setLineDash(dash || []);
    ctx.beginPath(); ctx.moveTo(a[0], a[1]); ctx.lineTo(b[0], b[1]); ctx.stroke(); ctx.setLineDash([]);
  }
  function skeleton(cv, ctx, xyz, c, colour, width, dash) {
    DATA.parents.forEach(function (p, j) {
      if (p >= 0 && xyz[j] && xyz[p]) line(ctx, project(cv, xyz[j], c), project(cv, xyz[p], c), colour, width, dash);
    });
  }
  function drawOne(k) {
    var take = DATA.takes[state.take], sys = take.systems[k], cv = canvases[k], ctx = cv.getContext("2d");
    var f = state.frame, c = take.centre;
    ctx.fillStyle = "rgb(" + BG.join(",") + ")"; ctx.fillRect(0, 0, cv.width, cv.height);
    for (var g = -4; g <= 4; g++) {
      var a = g * 500;
      line(ctx, project(cv, [c[0] + a, c[1] - 2000, 0], c), project(cv, [c[0] + a, c[1] + 2000, 0], c), "#3c3c3c", 1);
      line(ctx, project(cv, [c[0] - 2000, c[1] + a, 0], c), project(cv, [c[0] + 2000, c[1] + a, 0], c), "#3c3c3c", 1);
    }
    ctx.fillStyle = SURFACE;
    (sys.surface ? sys.surface[f] : []).forEach(function (p) {
      if (p) { var q = project(cv, p, c); ctx.beginPath(); ctx.arc(q[0], q[1], 1.8, 0, 2 * Math.PI); ctx.fill(); }
    });
    skeleton(cv, ctx, take.truth[f], c, TRUTH, 1.5, [4, 3]);
    skeleton(cv, ctx, sys.joints[f], c, SOLVED, 3);
    ctx.fillStyle = SOLVED;
    sys.joints[f].forEach(function (p) {
      if (p) { var q = project(cv, p, c); ctx.beginPath(); ctx.arc(q[0], q[1], 3, 0, 2 * Math.PI); ctx.fill(); }
    });
    var e = sys.error[f];
    cv.parentNode.querySelector("figcaption").textContent = sys.name + ": " +
      (e === null ? "no joints" : e.toFixed(1) + " mm MPJPE") + " at " + take.times[f].toFixed(2) + " s";
  }
  function painted(cv) {
    var px = cv.getContext("2d").getImageData(0, 0, cv.width, cv.height).data, n = 0;
    for (var i = 0; i < px.length; i += 16) {
      if (px[i] !== BG[0] || px[i + 1] !== BG[1] || px[i + 2] !== BG[2]) n += 4;
    }
    return n;
  }
  function draw() {
    var take = DATA.takes[state.take];
    canvases.forEach(function (cv, k) { drawOne(k); });
    label.textContent = "frame " + state.frame + " / " + (take.times.length - 1) + ", " +
      take.times[state.frame].toFixed(2) + " s";
    slider.value = state.frame;
  }
  function choose(index) {
    state.take = index; state.frame = 0;
    var take = DATA.takes[index];
    take.centre = take.centre || centre(take);
    views.innerHTML = ""; canvases = [];
    take.systems.forEach(function (sys) {
      var fig = document.createElement("figure"), cv = document.createElement("canvas");
      cv.width = 420; cv.height = 480; fig.appendChild(cv);
      fig.appendChild(document.createElement("figcaption")); views.appendChild(fig); canvases.push(cv);
      cv.addEventListener("mousedown", function (e) { drag = [e.clientX, e.clientY]; });
    });
    slider.max = take.times.length - 1;
    draw();
    document.body.setAttribute("data-take", take.id);
    document.body.setAttribute("data-frames", String(take.times.length));
    take.systems.forEach(function (sys, k) {
      document.body.setAttribute("data-painted-" + sys.name, String(painted(canvases[k])));
    });
  }
  function tick(now) {
    if (!state.playing) return;
    var take = DATA.takes[state.take];
    if (now - state.last >= 100) { state.last = now; state.frame = (state.frame + 1) % take.times.length; draw(); }
    requestAnimationFrame(tick);
  }
  var drag = null;
  window.addEventListener("mouseup", function () { drag = null; });
  window.addEventListener("mousemove", function (e) {
    if (!drag) return;
    state.az += (e.clientX - drag[0]) * 0.01;
    state.el = Math.max(-1.5, Math.min(1.5, state.el + (e.clientY - drag[1]) * 0.01));
    drag = [e.clientX, e.clientY]; draw();
  });
  DATA.takes.forEach(function (take, i) {
    var o = document.createElement("option"); o.value = i; o.textContent = take.id; select.appendChild(o);
  });
  select.addEventListener("change", function () { choose(Number(select.value)); });
  slider.addEventListener("input", function () { state.frame = Number(slider.value); draw(); });
  play.addEventListener("click", function () {
    state.playing = !state.playing; play.textContent = state.playing ? "pause" : "play";
    if (state.playing) requestAnimationFrame(tick);
  });
  document.addEventListener("keydown", function (e) {
    var n = DATA.takes[state.take].times.length;
    if (e.key === "ArrowRight") { state.frame = Math.min(state.frame + 1, n - 1); draw(); }
    if (e.key === "ArrowLeft") { state.frame = Math.max(state.frame - 1, 0); draw(); }
  });
  if (DATA.takes.length) choose(0);
})();
"""

"""The one interactive 3D view of mocapflow's pages (the report's and the compare page's): a page fragment with its
controls, its inline data and the script of viewer.js (canvas 2D, nothing fetched).

A page and not a Rerun recording: it opens in any browser, offline, with nothing to install, travels as one
file beside the report, and its test runs in a headless browser; rerun-sdk would add a large dependency and a
viewer program to every machine that looks at a take.

A page builds its data with the helpers here (``mm`` tracks, ``markers``/``points``/``skeleton`` layers, ``view``,
``entry``; viewer.js says what each holds) and passes it to :func:`viewer_html` with its options: what a sequence is
called, the canvas size, the span across its height, the tracks the view turns about, and whether several views
may be overlaid on one canvas.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

VIEWER_JS = Path(__file__).with_name("viewer.js").read_text()

SOLVED, TRUTH, SURFACE = "#ffa040", "#f0f0f0", "#4a90d9"  # solved joints (orange), the truth (dashed), a surface
TRUTH_DASH = [4, 3]

STYLE = ("#mf-controls{margin:.5em 0}#mf-controls>*{margin-right:.6em;vertical-align:middle}"
         "#mf-viewer{display:flex;gap:1em;align-items:flex-start;flex-wrap:wrap}"
         "#mf-views{display:flex;gap:.6em;flex-wrap:wrap}#mf-views figure{margin:0}"
         "#mf-views canvas{background:#1e1e1e;border-radius:4px;cursor:grab}#mf-views figcaption:empty{display:none}"
         "#mf-legend{list-style:none;padding:0;margin:0;font-size:12px;columns:2}#mf-legend li{white-space:nowrap}"
         "#mf-legend span{display:inline-block;width:10px;height:10px;border-radius:5px;margin-right:4px}")


def mm(a) -> list | None:
    """(frame, point, 3) m -> a track: nested lists of integer mm, None where missing."""
    if a is None:
        return None
    return [[None if not np.isfinite(p).all() else [round(float(c) * 1000) for c in p] for p in f] for f in a]


def markers(track: str, names: str) -> dict:
    """The markers of ``track``, each in its own colour, ``names`` the sequence's key of their names."""
    return {"track": track, "kind": "markers", "names": names, "radius": 4}


def points(track: str, colour: str, radius: float, *, tint: bool = False, overlay: bool = True) -> dict:
    """Dots of one colour (``tint``: the view's palette colour when overlaid; ``overlay`` False: left out then)."""
    return {"track": track, "kind": "points", "colour": colour, "radius": radius, "tint": tint, "overlay": overlay}


def skeleton(track: str, colour: str, width: float, dash: list[int] = (), *, tint: bool = False) -> dict:
    """The bones of ``track`` (the sequence's ``parents``)."""
    return {"track": track, "kind": "skeleton", "colour": colour, "width": width, "dash": list(dash), "tint": tint}


def view(name: str, layers: list[dict], painted: str, caption: dict | None = None) -> dict:
    """One canvas: its ``layers`` drawn in order; ``painted`` the body attribute of its drawn pixels; ``caption``
    {values: key of a value per frame, unit, missing: said for a null}."""
    return {"name": name, "layers": layers, "painted": painted, **({"caption": caption} if caption else {})}


def entry(label: str, colour: str, shape: str = "line", *, tint: bool = False) -> dict:
    """A legend entry: a dot or a square (``shape`` "dot" or "line"); ``tint``: hidden when the views are overlaid."""
    return {"label": label, "colour": colour, "shape": shape, "tint": tint}


def css_colours(bgr: list[tuple[int, int, int]]) -> list[str]:
    """OpenCV's BGR colours as CSS hex."""
    return ["#%02x%02x%02x" % (r, g, b) for b, g, r in bgr]


def viewer_html(sequences: list[dict], *, what: str, palette: list[tuple[int, int, int]], size=(720, 540),
                span_mm: float = 2600.0, centre: tuple[str, ...] = (), overlay: bool = False) -> str:
    """The view as a page fragment (its style is :data:`STYLE`): the controls, the canvases and legend, the script
    with ``sequences`` inline. ``what``: a sequence's name (the chooser's label, the body's ``data-<what>``);
    ``palette``: BGR colours of the markers and of views overlaid; ``span_mm`` across the canvas's height;
    ``centre``: the tracks whose mean the view turns about; ``overlay``: a button to overlay the views."""
    options = {"what": what, "width": size[0], "height": size[1], "span_mm": span_mm, "centre": list(centre),
               "palette": css_colours(palette), "overlay": overlay}
    data, opts = (json.dumps(d, separators=(",", ":")).replace("</", "<\\/") for d in ({"sequences": sequences},
                                                                                        options))
    return (f"<div id='mf-controls'><label>{what} <select id='mf-select'></select></label>"
            "<button id='mf-play'>play</button>" + ("<button id='mf-overlay'>overlay</button>" if overlay else "") +
            "<input id='mf-frame' type='range' min='0' value='0' style='width:320px'><span id='mf-label'></span></div>"
            "<div id='mf-viewer'><div id='mf-views'></div><ul id='mf-legend'></ul></div>"
            f"<script>\n{VIEWER_JS}\nvar DATA = {data};\nvar OPTIONS = {opts};\nmocapViewer(DATA, OPTIONS);\n</script>")

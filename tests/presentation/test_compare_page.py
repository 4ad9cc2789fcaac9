"""The compare page (presentation/compare.py) of a made-up comparison of three systems, drawn in a real headless
browser by the one 3D viewer (presentation/viewer.js): a canvas per system side by side, then overlaid; and the
comparison's text table and JSON figures."""

from __future__ import annotations

import html
import re

import cv2
import numpy as np

from browser import run_browser
from mocapflow.pipeline.compare import overall, score_take
from mocapflow.pipeline.registry import Capture, Skeleton
from mocapflow.presentation.compare import headline, table, write_compare_page
from mocapflow.tasks.shared.body import BODY_PARTS, JOINT_NAMES, PARENTS, Subject, rest_offsets

SYSTEMS = ("alpha", "beta", "gamma")
TEMPLATE = Skeleton(JOINT_NAMES, tuple(int(p) for p in PARENTS), BODY_PARTS)


def walk(frames: int) -> np.ndarray:
    """The template's rest pose moving 0.3 m along x over ``frames`` frames at 30 fps.  (frame, joint, 3) m"""
    offsets = rest_offsets(Subject(1.75, 1.0, 1.0, 1.0, 1.0, 1.0))
    rest = np.zeros_like(offsets)
    for j, p in enumerate(PARENTS):  # parents come before their children
        rest[j] = (rest[p] if p >= 0 else 0.0) + offsets[j]
    return rest + np.linspace(0.0, 0.3, frames)[:, None, None] * [1.0, 0.0, 0.0]


def comparison() -> dict:
    """alpha at 30 fps, beta at 10 fps with a surface and a joint missing in one frame, gamma at 30 fps: they meet
    at the 10 instants of beta's frames."""
    rng = np.random.default_rng(0)
    truth = walk(30)
    captures = {}
    for name, fps, noise in zip(SYSTEMS, (30.0, 10.0, 30.0), (0.03, 0.015, 0.01)):
        seen = truth[::int(30 / fps)]
        joints = seen + rng.normal(0.0, noise, seen.shape)
        surface = None
        if name == "beta":
            joints[2, 3] = np.nan
            surface = np.repeat(seen, 3, axis=1) + rng.normal(0.0, 0.05, (len(seen), 60, 3))
        captures[name] = Capture(f"{name}_stage", fps, joints, seen, surface_error_mm=None if surface is None else
                                 np.full(len(seen), 6.0), surface=surface, needs={"cameras": "2"}, skeleton=TEMPLATE)
    takes = {"squat": score_take("squat", captures, dict.fromkeys(SYSTEMS, 1.5))}
    return {"systems": list(SYSTEMS), "takes": takes, "requirements": dict.fromkeys(SYSTEMS, ""), "skeleton": TEMPLATE,
            "overall": {s: overall([t["systems"][s] for t in takes.values()], TEMPLATE) for s in SYSTEMS}}


def test_the_text_table_and_the_json_figures_name_every_system():
    result = comparison()
    text = table(result)
    assert text.splitlines()[0].split()[:3] == ["system", "MPJPE", "mm"]
    assert [line.split()[0] for line in text.splitlines()[1:4]] == list(SYSTEMS)
    assert "beta: cameras 2" in text
    figures = headline(result)
    assert figures["compare_frames"] == 10 and "compare_beta_surface_mm" in figures
    assert "compare_alpha_surface_mm" not in figures


def test_the_page_draws_every_system_side_by_side_and_overlaid(tmp_path):
    files = write_compare_page(tmp_path / "page", comparison(), title="three systems")
    page = tmp_path / "page" / "compare.html"
    assert files[-1] == page and page.read_text().count("function mocapViewer(") == 1  # the one viewer, once
    dom = run_browser(page, tmp_path, "--dump-dom")
    assert dom.returncode == 0, dom.stderr[-2000:]
    body = re.search(r"<body[^>]*>", dom.stdout).group(0)
    assert 'data-take="squat"' in body and 'data-frames="10"' in body, body
    for system in SYSTEMS:  # one canvas per system, each drawn (floor grid, truth, its joints)
        assert int(re.search(rf'data-painted-{system}="(\d+)"', body).group(1)) > 2000, body
    text = html.unescape(dom.stdout)
    assert re.search(r"alpha: \d+\.\d mm MPJPE at 0\.00 s", text) and "frame 0 / 9, 0.00 s" in text
    assert "the truth (dashed)" in text and "its surface" in text  # the legend, beta having a surface

    shot = run_browser(page, tmp_path, f"--screenshot={tmp_path / 'side.png'}", "--window-size=1400,1400")
    assert shot.returncode == 0, shot.stderr[-2000:]
    img = cv2.imread(str(tmp_path / "side.png")).astype(int)
    orange = (np.abs(img - [64, 160, 255]).max(axis=-1) <= 30)  # the solved joints (BGR of #ffa040)
    blue = (np.abs(img - [217, 144, 74]).max(axis=-1) <= 30)  # beta's surface (#4a90d9)
    assert orange.sum() > 300 and blue.sum() > 50
    columns = np.flatnonzero(orange.any(axis=0))
    assert columns.max() - columns.min() > 840  # joints drawn in three canvases 420 px wide, side by side

    overlaid = tmp_path / "page" / "overlaid.html"  # the same page, its overlay button pressed once drawn
    overlaid.write_text(page.read_text().replace("</body>", "<script>document.getElementById('mf-overlay')"
                                                            ".click();</script></body>"))
    dom = run_browser(overlaid, tmp_path, "--dump-dom")
    body = re.search(r"<body[^>]*>", dom.stdout).group(0)
    assert 'data-overlay="true"' in body and int(re.search(r'data-painted-overlay="(\d+)"', body).group(1)) > 2000
    assert dom.stdout.count("<canvas") == 1 and "side by side</button>" in dom.stdout
    legend = re.search(r"<ul id=\"mf-legend\">(.*?)</ul>", dom.stdout).group(1)
    assert [n for n in SYSTEMS if n in legend] == list(SYSTEMS) and "its surface" not in legend

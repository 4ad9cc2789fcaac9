"""`mocapflow report` on a user's own take (no ground truth): per-marker tracked frames and gaps, trajectories and the
interactive 3D view, the view checked in a real headless browser."""

from __future__ import annotations

import html
import re

import cv2
import numpy as np
import pytest

from browser import run_browser
from conftest import mocapflow
from mocapflow.presentation.report import gaps

FPS, FRAMES = 60, 60
MISSING = {"RASI": [range(10, 20), range(50, 55)], "LASI": [], "STRN": [range(0, 3)]}  # frames without a sample


def write_take(path):
    """A TRC take of three markers circling at known radii, with the gaps of MISSING."""
    names = list(MISSING)
    lines = ["PathFileType\t4\t(X/Y/Z)\ttake.trc",
             "DataRate\tCameraRate\tNumFrames\tNumMarkers\tUnits\tOrigDataRate\tOrigDataStartFrame\tOrigNumFrames",
             f"{FPS}\t{FPS}\t{FRAMES}\t{len(names)}\tmm\t{FPS}\t1\t{FRAMES}",
             "Frame#\tTime\t" + "\t\t\t".join(names) + "\t\t",
             "\t\t" + "\t".join(f"X{i + 1}\tY{i + 1}\tZ{i + 1}" for i in range(len(names)))]
    for f in range(FRAMES):
        cells = []
        for m, name in enumerate(names):
            gone = any(f in r for r in MISSING[name])
            a = 2 * np.pi * f / FRAMES
            cells += ["", "", ""] if gone else [f"{(300 + 100 * m) * np.cos(a):.3f}", f"{(300 + 100 * m) * np.sin(a):.3f}",
                                                f"{900 + 100 * m:.3f}"]
        lines.append(f"{f + 1}\t{f / FPS:.5f}\t" + "\t".join(cells))
    path.write_text("\n".join(lines) + "\n")


def test_gaps_are_the_runs_of_missing_frames():
    present = np.ones(12, bool)
    present[[0, 1, 5, 9, 10, 11]] = False
    assert gaps(present) == [(0, 2), (5, 1), (9, 3)]
    assert gaps(np.ones(4, bool)) == [] and gaps(np.zeros(3, bool)) == [(0, 3)]


@pytest.fixture(scope="module")
def own_report(tmp_path_factory):
    """`mocapflow report` of a catalog reading one TRC take (no ground truth): the report's folder."""
    tmp_path = tmp_path_factory.mktemp("own")
    (tmp_path / "takes").mkdir()
    write_take(tmp_path / "takes" / "walk01.trc")
    (tmp_path / "catalog.yaml").write_text(
        "data_roots: [.]\nstorage: {root: storage/}\n"
        "datasets:\n  lab: {kind: markers, path: takes, pattern: '*.trc', up: z, labels: use}\n"
        "stages:\n  markers: {task: ingest_markers, dataset: lab}\n")
    proc = mocapflow("report", "--catalog", "catalog.yaml", "--out", "rep", cwd=tmp_path)
    assert "wrote rep/report.html" in proc.stdout
    return tmp_path / "rep"


def test_report_of_an_own_take_without_ground_truth(own_report):
    page = (own_report / "report.html").read_text()
    assert "No ground truth in these recordings" in page and "<h3 id='seq-walk01'>walk01</h3>" in page
    rows = {cells[0]: cells[1:] for cells in (re.findall(r"<td>([^<]*)</td>", row)
                                              for row in re.findall(r"<tr>(<td>.*?)</tr>", page)) if len(cells) == 5}
    # marker: tracked %, gaps, longest gap (frames), longest gap (s)
    assert rows["RASI"] == ["75", "2", "10", "0.167"]
    assert rows["LASI"] == ["100", "0", "0", "0"]
    assert rows["STRN"] == ["95", "1", "3", "0.05"]
    png = cv2.imread(str(own_report / "trajectories_walk01.png"))
    assert png is not None and (png < 250).any(axis=-1).mean() > 0.02  # axes, lines and legend drawn


def test_the_3d_view_runs_and_draws_in_a_headless_browser(own_report, tmp_path):
    dom = run_browser(own_report / "report.html", tmp_path, "--dump-dom")
    assert dom.returncode == 0, dom.stderr[-2000:]
    body = re.search(r"<body[^>]*>", dom.stdout).group(0)
    assert 'data-frames="60"' in body and 'data-sequence="walk01"' in body, body
    painted = int(re.search(r'data-painted="(\d+)"', body).group(1))
    assert painted > 2000, body  # the floor grid and the markers drawn over the background
    assert "frame 0 / 59, 0.00 s, 2 of 3 markers" in html.unescape(dom.stdout)  # STRN is missing at frame 0

    shot = run_browser(own_report / "report.html", tmp_path, f"--screenshot={tmp_path / 'shot.png'}",
                       "--window-size=1200,2400")
    assert shot.returncode == 0, shot.stderr[-2000:]
    img = cv2.imread(str(tmp_path / "shot.png"))
    dark = (np.abs(img.astype(int) - 30).max(axis=-1) <= 1)  # the canvas's background
    assert dark.sum() > 200_000  # the 720 x 540 canvas is on the page ...
    ys, xs = np.nonzero(dark)
    canvas = img[ys.min():ys.max(), xs.min():xs.max()]
    assert (np.abs(canvas.astype(int) - 30).max(axis=-1) > 40).sum() > 500  # ... with markers and grid on it

"""The report's 2D overlay (estimates filled, recovered estimates hollow, true positions as rings) and the worst
markers against ground truth (their table and error plot over time)."""

import re

import cv2
import numpy as np

from mocapflow.presentation.report import PALETTE, Take, write_report
from mocapflow.systems.deepmocap.report import overlay


def test_overlay_draws_a_recovered_estimate_hollow():
    ir = np.full((60, 80), 500.0)
    ir[0, 0] = 1000.0  # the gain: the body at about half scale
    xy = np.array([[20.0, 30.0], [50.0, 30.0], [np.nan, np.nan]])
    gt = np.array([[np.nan, np.nan], [np.nan, np.nan], [65.0, 15.0]])
    img = overlay(ir, xy, gt, ["A", "B", "C"], "", np.array([False, True, False]))
    background = img[45, 5].copy()
    assert (img[30, 20] != background).any()  # a plain estimate: a filled dot
    np.testing.assert_array_equal(img[30, 50], background)  # a recovered one: its centre left as it was ...
    assert (img[30, 53] != background).any()  # ... inside a ring of its colour
    np.testing.assert_array_equal(img[15, 71], [255, 255, 255])  # the true position of C: a white ring
    np.testing.assert_array_equal(img[15, 65], background)
    plain = overlay(ir, xy, gt, ["A", "B", "C"], "")
    assert (plain[30, 50] != background).any()  # without the flag every estimate is filled


def take_with_truth() -> Take:
    """40 frames at 20 fps of 6 markers 1 mm from the truth, but FLY 2 m off in frames 10-14, SLIP 12 cm off in
    frames 20-22 and untracked in frame 30, and M5 50 mm off in frame 7."""
    names = ["M0", "M1", "FLY", "M3", "SLIP", "M5"]
    a = 2 * np.pi * np.arange(40) / 40
    gt = np.stack([np.stack([(0.3 + 0.1 * m) * np.cos(a), (0.3 + 0.1 * m) * np.sin(a), np.full(40, 1.0 + 0.1 * m)], -1)
                   for m in range(6)], 1)  # (frame, marker, 3) m
    position = gt + [0.001, 0.0, 0.0]
    position[10:15, 2] = gt[10:15, 2] + [0.0, 0.0, 2.0]
    position[20:23, 4] = gt[20:23, 4] + [0.12, 0.0, 0.0]
    position[30, 4] = np.nan
    position[7, 5] = gt[7, 5] + [0.0, 0.05, 0.0]
    return Take("walk", 20.0, "walk", "checked", names, position, gt_markers=gt)


def test_the_worst_markers_against_ground_truth_are_tabled_and_plotted(tmp_path):
    take = take_with_truth()
    bare = Take("bare", 20.0, "", "checked", take.names, take.position)  # no ground truth: no section
    page = write_report(tmp_path, [take, bare], title="t", summary={}, accuracy=None).read_text()
    assert page.count("Worst markers against ground truth") == 1 and not (tmp_path / "worst_markers_bare.png").exists()
    section = page[page.index("Worst markers against ground truth"):]
    rows = [re.findall(r"<td>([^<]*)</td>", r) for r in re.findall(r"<tr>(<td>.*?)</tr>", section)][:5]
    # marker, max (mm), at frame, at (s), p95 (mm), > 10 cm (frames), > 10 cm (% of the frames tracked)
    # FLY: 35 x 1 mm, 5 x 2000 mm, p95 at rank 0.95 * 39 = 37.05 -> 2000; SLIP: 36 x 1 mm, 3 x 120 mm of 39 frames
    # tracked, p95 at rank 0.95 * 38 = 36.1 -> 120; M5 ties the rest's p95 (1 mm), first by its maximum
    assert rows[0] == ["FLY", "2000", "10", "0.5", "2000", "5", "12.5"]
    assert rows[1] == ["SLIP", "120", "20", "1", "120", "3", "7.7"]
    assert rows[2] == ["M5", "50", "7", "0.35", "1", "0", "0"]
    assert [r[0] for r in rows[3:]] == ["M0", "M1"] and rows[3][1] == "1" and rows[3][5] == "0"

    png = cv2.imread(str(tmp_path / "worst_markers_walk.png"))
    assert png is not None and png.shape == (420, 980, 3)
    assert (png < 250).any(axis=-1).mean() > 0.02  # axes, lines, legend drawn
    for k in range(5):  # each of the five worst drawn in its colour
        assert (np.abs(png.astype(int) - PALETTE[k]).max(axis=-1) <= 10).sum() > 30, k
    # FLY's excursion to 2000 mm (log axis 1 mm - 10 m, y 40-370 px) sits high, 1 mm at the bottom
    fly = np.abs(png.astype(int) - PALETTE[0]).max(axis=-1) <= 10
    rows_of_fly = np.flatnonzero(fly[:, 60:800].any(axis=1))
    assert rows_of_fly.min() < 40 + 0.3 * 330 and rows_of_fly.max() > 360

"""`mocapflow demo` end to end at a reduced size: every stage through the engine with the shipped
weights, the accuracy table, BVH + C3D + report written; the second run is served from the cache."""

import json

import cv2

from browser import run_browser
from conftest import last_json, mocapflow
from mocapflow.formats.bvh import read_bvh_joints
from mocapflow.formats.c3d import read_points as read_c3d

# Floor of the shipped FCN weights on this smoke run: the pose goals (measured PCK@20cm 100 %, PCK@5cm
# 90.8 %, MAE 2.47 cm at 40 frames; 100 %, 98.6 %, 1.72 cm at the 30 frames run here; procedural motion, so not an
# accuracy figure of the system, see docs/results.md), which leave room for BLAS differences.
FLOOR = {"pck3d_20cm": 0.98, "pck3d_5cm": 0.80, "mae3d_cm": 3.0}


def test_demo_runs_everything_and_is_served_from_cache_the_second_time(tmp_path):
    # 30 frames: the fewest the demo accepts (enough to calibrate a skeleton)
    args = ("demo", "--out", "demo", "--frames", "30", "--motion", "jumping_jack", "--json")
    first = last_json(mocapflow(*args, cwd=tmp_path, timeout=900))
    assert first["partitions computed"] == 21 and first["poses_solved"] == 1.0  # 5 stages x 3 views, 6 x 1 sequence
    assert first["map2d_refined"] > first["map2d"] > 0.9, first  # the labels refined from the poses gain
    assert first["pck3d_20cm"] >= FLOOR["pck3d_20cm"] and first["pck3d_5cm"] >= FLOOR["pck3d_5cm"], first
    assert first["mae3d_cm"] <= FLOOR["mae3d_cm"], first
    out = tmp_path / "demo"
    joints, names, _ = read_bvh_joints(out / "export" / "jumping_jack_s1.bvh")
    assert joints.shape == (30, 20, 3) and names[0] == "Hips"
    xyz, labels, rate, _ = read_c3d(out / "export" / "jumping_jack_s1.c3d")
    assert xyz.shape == (30, 26, 3) and rate == 30.0
    for png in ("reflectors", "skeleton", "pck", "joint_errors", "worst_markers_jumping_jack_s1"):
        img = cv2.imread(str(out / "report" / f"{png}.png"))
        assert img is not None and img.std() > 5, png  # drawn, not blank
    page = (out / "report" / "report.html").read_text()
    assert "reflectors.png" in page and "jumping_jack_s1.bvh" in page
    pck = first["pck3d_20cm"] * 100
    assert f"<td>3D PCK @ 20 cm, Table 8 joints</td><td>{pck:.4g} %</td>" in page  # named, in %
    assert "MAE cm" in page and "PCK@20cm" in page  # the accuracy tables, in units and %
    assert "<h3 id='seq-jumping_jack_s1'>jumping_jack_s1 (jumping_jack)</h3>" in page  # a named sequence
    assert "median residual (mm)" in page and "views (mean)" in page
    assert "Worst markers against ground truth" in page and "worst_markers_jumping_jack_s1.png" in page
    dom = run_browser(out / "report" / "report.html", tmp_path, "--dump-dom")  # the 3D view with its skeletons
    assert dom.returncode == 0 and 'data-frames="30"' in dom.stdout, dom.stderr[-2000:]
    assert "solved skeleton" in dom.stdout and "ground-truth skeleton" in dom.stdout

    second = last_json(mocapflow(*args, cwd=tmp_path, timeout=900))
    assert second["partitions computed"] == 0
    assert json.dumps({k: first[k] for k in FLOOR}) == json.dumps({k: second[k] for k in FLOOR})

"""The shipped recorded-C3D example (benchmarks/uuo_c3d_example.yaml) runs as written, markers only, on the
tennis serve of ../shared/data/c3d: the solve labels part of the trajectories, and `mocapflow report` shows the
solved body without a truth to score it against (a shorter window than the example's, for time)."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

from conftest import mocapflow, read_artifacts
from shared_data import ROOT, skip_unless_beside_checkout

EXAMPLE = ROOT / "benchmarks" / "uuo_c3d_example.yaml"
TAKE = "ktk_kinematics_tennis_serve"


@pytest.mark.needs_shared
def test_the_recorded_c3d_example_runs_markers_only_and_reports_the_solved_body(tmp_path):
    skip_unless_beside_checkout(EXAMPLE.name)
    sets = ("--catalog", EXAMPLE, "--set", f"storage.root={tmp_path / 'storage'}",
            "--set", "datasets.recorded.frames=[690, 695]")
    mocapflow("run", *sets, cwd=tmp_path, timeout=1500)
    stored = {pid: arrays for (pid, _), arrays in read_artifacts(tmp_path / "storage").items()}
    markers, prior, body = stored[f"markers/{TAKE}"], stored[f"prior/{TAKE}"], stored[f"body/{TAKE}"]
    assert markers["position"].shape == (5, 39, 3)  # the serve's 39 trajectories, 5 frames of the window
    assert np.isfinite(prior["joints"]).all()  # no_prior: the rest body
    assert body["joints"].shape == (5, 20, 3) and np.isfinite(body["joints"]).all()
    labelled = int((body["vertex"] >= 0).sum())
    assert 0 < labelled <= 39  # markers only: a vertex for part of them
    proc = mocapflow("report", *sets, "--out", "rep", cwd=tmp_path, timeout=600)
    assert f"wrote rep/markers_on_mesh_{TAKE}.png" in proc.stdout and "joint_errors" not in proc.stdout  # no truth
    img = cv2.imread(str(tmp_path / "rep" / f"markers_on_mesh_{TAKE}.png"))
    assert img.shape == (420, 840, 3) and len(np.unique(img.reshape(-1, 3), axis=0)) > 20
    page = (tmp_path / "rep" / "report.html").read_text()
    assert "No ground truth in these recordings" in page and f"markers_on_mesh_{TAKE}.png" in page
    seq = json.JSONDecoder().raw_decode(page.split("var DATA = ", 1)[1])[0]["sequences"][0]
    assert seq["markers"][:2] == ["m000", "m001"]  # the file's labels not read (labels: ignore)
    assert len(seq["joints"]) == 20 and np.isfinite(np.array(seq["joint_xyz"], float)).all()  # the solve's joints

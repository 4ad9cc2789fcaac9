"""`mocapflow report` on a suit studio catalog: the suit's corners as the page's takes (a subsample, said so), the
labelled corners over a camera image with the truth, the filled suit in 3D and the errors' histograms."""

from __future__ import annotations

import json

import cv2
import numpy as np

from conftest import mocapflow, read_artifacts
from shared_runs import copy_run, shared_run
from studio_catalogs import SUIT_CATALOG as CATALOG


FIGURES = ("suit_labels_sq", "suit_corners_3d_sq", "suit_reprojection_error", "suit_error_3d", "trajectories_sq",
           "worst_markers_sq")


def viewer_data(page: str) -> dict:
    """The 3D viewer's data embedded in a report page."""
    return json.JSONDecoder().raw_decode(page.split("var DATA = ", 1)[1])[0]


def check_png(path) -> np.ndarray:
    """An image that exists, has a size and is not one flat colour."""
    img = cv2.imread(str(path))
    assert img is not None, f"{path} missing or unreadable"
    assert min(img.shape[:2]) >= 200, img.shape
    assert len(np.unique(img.reshape(-1, 3), axis=0)) > 20, f"{path} is nearly flat"
    return img


def test_the_report_of_a_suit_catalog_shows_its_corners_and_the_filled_suit(request, tmp_path):
    shared_run(request, "suit", CATALOG)  # the pytest run's one run of the catalog (the engine's test reads it too)
    project = copy_run(request, "suit", tmp_path / "project")
    proc = mocapflow("report", "--out", "rep", cwd=project, timeout=600)
    for name in FIGURES:
        assert f"wrote rep/{name}.png" in proc.stdout
        check_png(project / "rep" / f"{name}.png")
    page = (project / "rep" / "report.html").read_text()
    assert all(f'src="{name}.png"' in page or f"src='{name}.png'" in page for name in FIGURES)
    stored = {pid: arrays for (pid, _), arrays in read_artifacts(project / "storage").items()}
    filled, images = stored["filled/sq"], stored["images/sq"]
    n = filled["position"].shape[1]
    seq = viewer_data(page)["sequences"][0]
    step = int(np.ceil(n / 150))
    assert n > 1000 and len(seq["markers"]) == len(range(0, n, step)) <= 150  # an even subsample of the corners
    assert f"{len(seq['markers'])} of the {n} corners of the suit (every {step}th)" in page  # and the page says so
    shown = np.array(seq["marker_xyz"], float) / 1000  # m, rounded to the mm
    np.testing.assert_allclose(shown, filled["position"][:, ::step], atol=6e-4)
    assert seq["markers"][0] and all(isinstance(m, str) and m for m in seq["markers"])  # named by code and vertex
    assert "suit: occluded patches filled, 3D error median" in page  # the evaluation's headline, named
    assert "suit: 3D error through perturbed calibration, median" in page
    three_d = check_png(project / "rep" / "suit_corners_3d_sq.png")
    assert three_d.shape == (600, 1200, 3)  # front and side
    frame = filled["position"].shape[0] // 2  # the figure's frame: filled (orange) and observed (green) corners
    assert (~filled["observed"][frame]).any() and filled["observed"][frame].any()
    orange = ((three_d[..., 2] > 200) & (three_d[..., 1] > 100) & (three_d[..., 1] < 180) & (three_d[..., 0] < 60))
    green = ((three_d[..., 1] > 150) & (three_d[..., 0] < 100) & (three_d[..., 2] < 100))
    assert orange.sum() > 500 and green.sum() > 200
    assert images["image"].shape[0] == 4  # the labels' figure picks one of the 4 views

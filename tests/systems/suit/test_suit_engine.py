"""The suit system through the engine: studio takes filmed by grey cameras, labels, triangulation, hold-out and
evaluation, cached like every stage."""

from __future__ import annotations

import numpy as np

from conftest import last_json, mocapflow, read_artifacts
from shared_runs import copy_run, shared_run
from studio_catalogs import SUIT_CATALOG as CATALOG
from mocapflow.tasks.shared.cameras import camera_of


def test_suit_takes_are_labelled_triangulated_and_scored_through_the_engine(request, tmp_path):
    first = shared_run(request, "suit", CATALOG)  # the pytest run's one run of the catalog (the report reads it too)
    project = copy_run(request, "suit", tmp_path / "project")
    assert sorted(first["executed"]) == sorted(["images/sq", "points/sq", "perturbed/sq", "hidden/sq", "filled/sq"]
                                               + [f"labels/sq/cam{v:02d}" for v in range(4)])
    stored = {pid: arrays for (pid, _), arrays in read_artifacts(project / "storage").items()}
    images, points = stored["images/sq"], stored["points/sq"]
    assert images["image"].shape == (4, 3, 512, 384) and images["gt_corners"].shape[1] > 1000
    ds = _calibration(images)
    for v in range(4):
        xy, _ = camera_of(ds, f"cam{v:02d}").project(images["gt_corners"][1].astype(np.float64))
        seen = images["gt_visible"][v, 1]
        np.testing.assert_allclose(xy[seen], images["gt_corners2d"][v, 1][seen], atol=1e-3)
    ok = np.isfinite(points["position"]).all(axis=-1)
    error = np.linalg.norm(points["position"][ok] - images["gt_corners"][ok], axis=-1)
    # 0.2 px noise at ~0.25 px per mm: measured a median of 1.20 mm
    assert ok.sum() > 500 and np.median(error) < 0.0016, np.median(error)
    hidden = stored["hidden/sq"]["hidden"]
    assert hidden.any() and not np.isfinite(stored["hidden/sq"]["position"][hidden]).any()
    # patches added until a fifth of the observations is hidden: measured 0.207, the last patch a little over
    assert 0.2 <= hidden.sum() / ok.sum() < 0.25, hidden.sum() / ok.sum()
    filled = stored["filled/sq"]
    seen = np.isfinite(stored["hidden/sq"]["position"]).all(axis=-1)
    np.testing.assert_array_equal(filled["observed"], seen)
    np.testing.assert_array_equal(filled["position"][seen], stored["hidden/sq"]["position"][seen])
    assert np.isfinite(filled["position"]).all()  # every corner of every frame
    scores = last_json(mocapflow("evaluate", "--json", cwd=project))  # cached: scores only
    # patches (measured a median of 2.43 mm over the hidden corners)
    assert scores["suit_fill_occluded_median_mm"] < 3.2 and "suit_fill_err_median_mm" not in scores, scores
    # 2 % planted misreads (78 measured): the detect rate measured 0.981
    assert scores["suit_wrong_labels"] > 0 and 0.96 < scores["suit_detect_rate"] < 1.0, scores
    assert scores["suit_visible_rate"] < scores["suit_detect_rate"]  # visible corners include unreadable ones
    # of about 80 planted misreads, the outlier rule lets 1 through on this 4-camera take (measured): it is the one
    # corner put more than 5 mm off
    assert scores["suit_err3d_over_5mm"] <= scores["suit_wrong_labels_in_3d"] <= 2
    assert abs(scores["suit_err3d_median_mm"] - np.median(1000 * error)) < 1e-3
    # a quarter-pixel calibration error costs more than the labels' 0.2 px of noise alone, but stays millimetric
    # (measured 1.20 and 1.83 mm)
    assert scores["suit_err3d_median_mm"] < scores["suit_err3d_perturbed_median_mm"] < 2.5, scores
    again = last_json(mocapflow("run", "--json", cwd=project))
    assert again["executed"] == []
    _check_exports(project, filled, images)


def _check_exports(tmp_path, filled: dict, images: dict) -> None:
    """C3D: one point per corner named by its first key, the filled positions in mm; PLY: every corner of each frame
    with its observed flag, the cells as two triangles each."""
    import ezc3d

    mocapflow("export", "--format", "c3d", "--stage", "filled", "--out", "exp", cwd=tmp_path)
    c3d = ezc3d.c3d(str(tmp_path / "exp" / "sq.c3d"))
    group = c3d["parameters"]["POINT"]  # over 255 points the labels go on in LABELS2, LABELS3, ... (the C3D spec)
    labels = [name for key in ["LABELS"] + [f"LABELS{i}" for i in range(2, 100)] if key in group
              for name in group[key]["value"]]
    assert len(labels) == images["gt_corners"].shape[1] and len(set(labels)) == len(labels)
    code, corners = str(images["code"][0]), images["square_corners"][0]
    assert labels[corners[2]] in (f"{code}2", *(f"{c}{k}" for c in images["code"] for k in range(4)))
    points = c3d["data"]["points"][:3].transpose(2, 1, 0)  # (frame, corner, xyz) mm
    np.testing.assert_allclose(points, filled["position"] * 1000, atol=1e-2)
    mocapflow("export", "--format", "ply", "--out", "meshes", cwd=tmp_path)
    text = (tmp_path / "meshes" / "sq" / "frame_000001.ply").read_text().splitlines()
    n = filled["position"].shape[1]
    assert f"element vertex {n}" in text and f"element face {2 * len(images['cells'])}" in text
    start = text.index("end_header") + 1
    flags = np.array([int(line.split()[3]) for line in text[start:start + n]])
    np.testing.assert_array_equal(flags, filled["observed"][1])
    xyz = np.array([[float(v) for v in line.split()[:3]] for line in text[start:start + n]])
    np.testing.assert_allclose(xyz, filled["position"][1], atol=2e-6)


def _calibration(images: dict):
    import xarray as xr

    views = [f"cam{v:02d}" for v in range(4)]
    return xr.Dataset({k: (("view",) + (("dist_coef",) if k == "dist" else ("row", "col") if k == "cam_to_world"
                                        else ()), images[k]) for k in ("fx", "fy", "cx", "cy", "dist", "cam_to_world",
                                                                        "width", "height")},
                      coords={"view": views})


CHAIN = """\
data_roots: [.]
storage: {root: storage/, region_frames: 2}
datasets:
  suits:
    kind: studio_suit
    suit: medium
    cameras: {count: 4, width: 768, height: 1024, view_height_m: 1.3}
    defaults: {frames: 2}
    sequences:
      lunge: {motion: forward_lunge_left_right, seed: 12}
stages:
  images: {task: ingest_suit, dataset: suits}
  corners: {task: find_corners, inputs: [images]}
  quads: {task: find_quads, inputs: {images: images, corners: corners}}
  codes: {task: read_codes, inputs: {images: images, corners: corners, quads: quads}}
  labels: {task: label_corners, inputs: {images: images, corners: corners, quads: quads, codes: codes}}
  points: {task: triangulate_corners, inputs: {labels: labels, images: images}}
"""


def test_the_2d_chain_labels_corners_with_the_shipped_networks(tmp_path):
    """Corners, quads, codes and labels on a held-out suit and subject: labelled corners sit on their true pixels,
    and a changed reading threshold recomputes the codes and what follows them only."""
    (tmp_path / "catalog.yaml").write_text(CHAIN)
    scores = last_json(mocapflow("evaluate", "--json", cwd=tmp_path))
    # measured 0.622 on this take (the sewn suit; 0.49 on the UV-chart print): 0.57 fails a loss of a twelfth of the
    # detections, well before the print's level
    assert scores["suit_detect_rate"] > 0.57, scores
    assert scores["suit_visible_rate"] < scores["suit_detect_rate"]
    assert scores["suit_wrong_label_rate"] < 0.005, scores  # measured 6 of 2,071 labels (0.0029)
    assert scores["suit_err3d_over_5mm"] == 0
    assert scores["suit_loc_err_px"] < 0.16, scores  # measured 0.126 px
    assert scores["suit_err3d_median_mm"] < 0.3, scores  # measured 0.198 mm
    stored = {pid: arrays for (pid, _), arrays in read_artifacts(tmp_path / "storage").items()}
    labels, images = stored["labels/lunge/cam00"], stored["images/lunge"]
    hit = np.isfinite(labels["x"][0])
    assert hit.sum() > 50 and labels["quads"][0][hit].min() >= 1
    xy = np.stack([labels["x"][0], labels["y"][0]], axis=-1)[hit]
    assert np.median(np.linalg.norm(xy - images["gt_corners2d"][0, :][hit], axis=-1)) < 0.3
    # the dry run's plan is what a run would compute (run executes exactly the partitions it plans)
    again = last_json(mocapflow("run", "--dry-run", "--json", "--set", "stages.codes.params.read.min_confidence=0.6",
                                cwd=tmp_path))
    assert sorted({p.split("/")[0] for p in again["planned"]}) == ["codes", "labels", "points"]

"""The plausibility of each view's labels in `mocapflow evaluate` and `mocapflow report`: on a studio take whose
view kinect0 reads the legs under the other side's labels (the toy plug-in's `exchanged_reflectors`, the true 2D
reflectors otherwise), that view's left/right and on-body shares fall and track its true figures; on a recording
without truth (the DeepMoCap dataset's files, the default chain with the shipped network) the shares are the
evaluation, per view, and the report draws them."""

import re

import cv2
import numpy as np
import yaml

from conftest import PLUGINS, last_json, mocapflow
from mocapflow.cli.scaffold import DEFAULT_STAGES
from mocapflow.pipeline.catalog import load_catalog
from mocapflow.pipeline.evaluate import evaluate
from mocapflow.pipeline.plan import build_plan
from mocapflow.pipeline.storage import Store
from mocapflow.tasks.deepmocap.film.synth import build_rig, synthesize
from mocapflow.tasks.studio.spec import SequenceSpec
from test_dmc_files import write_dmc

CATALOG = """\
plugins: [toytasks]
storage: {root: storage/, region_frames: 8}
datasets:
  studio:
    kind: studio
    defaults: {frames: 16, views: 3}
    sequences:
      jj: {motion: jumping_jack, seed: 21}
stages:
  frames: {task: ingest, dataset: studio}
  masks: {task: reflector_mask, inputs: [frames]}
  reflectors2d: {task: exchanged_reflectors, inputs: [frames]}
  markers3d: {task: fuse_views, inputs: {reflectors: reflectors2d, masks: masks, frames: frames}}
  smoothed: {task: kalman, inputs: {markers: markers3d}}
  poses: {task: fit_body_poses, inputs: {markers: smoothed}}
"""


def test_a_view_reading_the_legs_exchanged_is_told_apart_by_its_plausibility(tmp_path, monkeypatch):
    (tmp_path / "catalog.yaml").write_text(CATALOG)
    proc = mocapflow("evaluate", "--json", cwd=tmp_path, timeout=600)
    figures = last_json(proc)
    assert "plausibility of each view's labels" in proc.stdout and "true 2D mAP %" in proc.stdout
    monkeypatch.syspath_prepend(str(PLUGINS))
    catalog = load_catalog(tmp_path / "catalog.yaml", ())
    result = evaluate(catalog, build_plan(catalog), Store(catalog.root))  # every artifact computed: read only
    views = result["plausibility"]["views"]
    assert set(views) == {"kinect0", "kinect1", "kinect2"} and result["plausibility"]["poses"] == "poses"
    clean = [views["kinect1"], views["kinect2"]]
    # the leg labels kinect0 sees (6 of its 22 sided ones) are on the wrong side and off the body
    assert views["kinect0"]["left_right"] < min(v["left_right"] for v in clean) - 0.1, views
    assert views["kinect0"]["on_body"] < min(v["on_body"] for v in clean) - 0.1, views
    assert set(views["kinect0"]["worst"]) & {"L_CALF", "R_CALF", "L_ANKLE", "R_ANKLE", "L_FOOT", "R_FOOT"}, views
    # the true labels (measured: agreement 89.0 and 93.2 %, left/right 100 and 98.9 %; kinect0 44.3 and 69.3 %)
    assert all(v["agreement"] > 0.8 and v["left_right"] > 0.95 for v in clean), views
    assert views["kinect0"]["agreement"] < min(v["agreement"] for v in clean), views
    # the truth agrees: kinect0 is the view with the lowest 2D AP and the fewest labels lifted onto their reflector
    true_map = {v: f["map"] for v, f in result["reflectors2d"]["per_view"].items()}
    assert min(true_map, key=true_map.get) == "kinect0", true_map
    assert min(views, key=lambda v: views[v]["true_on_reflector"]) == "kinect0", views
    for view, f in views.items():  # the on-body share tracks the truth it stands in for
        assert abs(f["on_body"] - f["true_on_reflector"]) < 0.1, (view, f)
    assert figures["plausibility_left_right_worst_view"] == views["kinect0"]["left_right"]
    assert 0 < figures["plausibility_on_body"] < 1 and figures["plausibility_agreement"] > 0.5, figures


def test_a_recording_without_truth_is_evaluated_and_reported_by_its_plausibility(tmp_path):
    take = synthesize(build_rig(SequenceSpec(motion="jumping_jack", frames=4, views=3, seed=1)), 0, 4)
    intrinsics = write_dmc(tmp_path / "recs" / "take1", take)
    stages = DEFAULT_STAGES[:DEFAULT_STAGES.index("  reflectors2d_refined:")].replace("dataset: recordings",
                                                                                       "dataset: dmc")
    (tmp_path / "catalog.yaml").write_text(
        yaml.safe_dump({"data_roots": ["."], "storage": {"root": "storage/"},
                        "datasets": {"dmc": {"kind": "dmc", "path": "recs", "intrinsics": intrinsics}}},
                       sort_keys=False) + stages)
    proc = mocapflow("evaluate", "--json", cwd=tmp_path, timeout=600)
    figures = last_json(proc)
    assert "plausibility of each view's labels" in proc.stdout and "true 2D mAP" not in proc.stdout, proc.stdout
    assert not any(k.startswith(("map2d", "pck3d", "marker_")) for k in figures), figures  # nothing needs truth
    for check in ("agreement", "left_right", "on_body"):
        assert 0.0 <= figures[f"plausibility_{check}_worst_view"] <= figures[f"plausibility_{check}"] <= 1.0, figures
    rows = [line.split() for line in proc.stdout.splitlines() if re.match(r"take1\s+\S*\s*kinect\d", line)]
    assert {r[1] if r[1].startswith("kinect") else r[2] for r in rows} == {"kinect0", "kinect1", "kinect2"}, rows
    # the shipped network labels a studio take's reflectors: most agree across views and sit on the body
    assert figures["plausibility_on_body"] > 0.5 and figures["plausibility_left_right"] > 0.8, figures

    proc = mocapflow("report", "--out", "rep", cwd=tmp_path, timeout=600)
    assert "wrote rep/plausibility.png" in proc.stdout, proc.stdout
    chart = cv2.imread(str(tmp_path / "rep" / "plausibility.png"))
    assert chart.shape[0] == 60 + 26 * 9 and (chart < 200).any()  # three views x three checks
    assert "plausibility" in (tmp_path / "rep" / "report.html").read_text()
    assert np.isfinite(figures["plausibility_on_body"])

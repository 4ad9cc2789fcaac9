"""Training as pipeline stages: a per-dataset partition reads every sequence, `mocapflow train` writes
plain-tensor weights reproducibly, caches them, and the inference stages run on what it wrote."""

import hashlib
import shutil
import subprocess
import sys

import numpy as np
import pytest
import torch

from conftest import env_with_plugins, last_json, mocapflow, wait_for
from shared_runs import copy_run, shared_run
from mocapflow.pipeline.catalog import load_catalog
from mocapflow.pipeline.plan import build_plan
from mocapflow.pipeline.storage import Store
from mocapflow.pipeline.training import export_weights
from mocapflow.schemas import get_schema

CATALOG = """\
data_roots: [.]
storage: {root: storage/, region_frames: 8}
datasets:
  train:
    kind: studio
    defaults: {frames: 6, views: 2, random_layout: true}
    sequences:
      jj: {motion: jumping_jack, seed: 11}
      squat: {motion: classic_squat, seed: 12, heading_deg: 150}
stages:
  frames: {task: ingest, dataset: train}
  masks: {task: reflector_mask, inputs: [frames]}
  flow: {task: dis, inputs: [frames]}
  samples: {task: fcn_samples, inputs: {masks: masks, flow: flow, frames: frames}}
  weights:
    task: train_fcn
    inputs: {samples: samples}
    params: {input_size: 64, stream_width: 8, fused_width: 8, stage_width: 8, stages: 2, iterations: 3, batch: 2,
             frame_step: 1, seed: 0}
"""
INFERENCE = CATALOG.split("  samples:")[0] + """\
  heatmaps: {task: fcn_heatmaps, inputs: {masks: masks, flow: flow}, params: {weights: model.pt}}
  reflectors2d: {task: greedy_reflectors, inputs: {heatmaps: heatmaps, masks: masks}}
"""


@pytest.fixture
def project(request, tmp_path):
    """A folder with CATALOG, its samples in storage/ and the network it trains as trained.pt: the catalog is run
    once per pytest run (shared_runs) and copied here, so that a test pays for its own trainings only. The
    copy's store holds no weights: every training of a test is its own."""
    shared_run(request, "fcn-training", CATALOG)
    folder = copy_run(request, "fcn-training", tmp_path / "project")
    store = Store(load_catalog(folder / "catalog.yaml", ()).root)
    item = build_plan(load_catalog(folder / "catalog.yaml", ())).items["weights/train"]
    export_weights(store, item, folder / "trained.pt")  # what `mocapflow train` writes from that artifact
    shutil.rmtree(folder / "storage" / "weights")
    shutil.rmtree(folder / "storage" / "logs")  # the tests read their own runs' logs
    return folder


def test_train_caches_reproduces_and_feeds_inference(project):
    shutil.rmtree(project / "storage" / "samples")  # computed by `train` itself (in a worker process), first
    first = last_json(mocapflow("train", "--catalog", "catalog.yaml", "--out", "model.pt", "--json", "--workers", "1",
                                cwd=project, timeout=600))
    data = (project / "model.pt").read_bytes()
    assert first["sha256"] == hashlib.sha256(data).hexdigest()
    weights = torch.load(project / "model.pt", weights_only=True)
    assert weights["architecture"]["input_size"] == 64 and weights["crop"]["sample_scale"] == 0.5

    catalog = load_catalog(project / "catalog.yaml", ())
    store = Store(catalog.root)
    trained = store.open("weights", first["key"], get_schema("fcn_weights"))
    assert trained.sizes["iteration"] == 3 and np.isfinite(trained["loss"].values).all()
    assert trained.attrs["training"]["samples"] == 2 * 2 * 6  # every (sequence, view, frame) with a reflector seen
    logs = list((project / "storage" / "logs").glob("run-*.log"))  # the training's progress is in the run's log
    assert len(logs) == 1 and "iteration 2/3: loss" in logs[0].read_text()

    again = last_json(mocapflow("train", "--catalog", "catalog.yaml", "--out", "again.pt", "--json", cwd=project))
    assert again["key"] == first["key"] and (project / "again.pt").read_bytes() == data  # cached, same bytes
    reseeded = last_json(mocapflow("train", "--catalog", "catalog.yaml", "--out", "other.pt", "--json",
                                   "--set", "stages.weights.params.seed=1", cwd=project, timeout=600))
    assert reseeded["key"] != first["key"] and reseeded["sha256"] != first["sha256"]

    (project / "infer.yaml").write_text(INFERENCE)
    run = last_json(mocapflow("run", "--catalog", "infer.yaml", "--json", "--workers", "1", cwd=project, timeout=600))
    assert not [p for p in run["executed"] if p.startswith(("frames", "masks", "flow"))]  # shared with training
    assert sorted(p for p in run["executed"] if p.startswith("reflectors2d")) == [
        f"reflectors2d/{s}/kinect{v}" for s in ("jj", "squat") for v in (0, 1)]
    plan = build_plan(load_catalog(project / "infer.yaml", ()))
    heat = store.open("heatmaps", plan.items["heatmaps/jj/kinect0"].key, get_schema("heatmaps"))
    assert heat["confidence"].shape == (1, 6, 26, 16, 16) and heat["off"].shape == (1, 6, 26, 16, 16, 2)
    est = store.open("reflectors2d", plan.items["reflectors2d/jj/kinect0"].key, get_schema("reflectors2d"))
    x, size = est["x"].values, est["region_size"].values
    assert ((x >= 0) & (x < 512))[np.isfinite(x)].all() and (size[np.isfinite(x)] >= 5).all()


def test_a_per_dataset_partition_reads_every_sequence(tmp_path):
    (tmp_path / "catalog.yaml").write_text(CATALOG)
    catalog = load_catalog(tmp_path / "catalog.yaml", ())
    both, one = build_plan(catalog), build_plan(catalog, "jj")
    item = both.items["weights/train"]
    assert sorted(item.depends_on) == sorted(f"samples/{s}/kinect{v}" for s in ("jj", "squat") for v in (0, 1))
    assert one.items["weights/train"].key != item.key  # the data is part of the key
    assert one.items["samples/jj/kinect0"].key == both.items["samples/jj/kinect0"].key


def test_batch_processes_draw_the_same_batches_whatever_their_number(project):
    def train(n: int, per_batch: bool, *options: str) -> dict:
        root = f"store{n}{per_batch}"  # each run in its own storage: nothing served from another's cache
        shutil.copytree(project / "storage", project / root)
        if options:
            shutil.rmtree(project / root / "samples")
        return last_json(mocapflow("train", "--catalog", "catalog.yaml", "--out", f"w{n}{per_batch}.pt", "--json",
                                   "--set", f"stages.weights.params.workers={n}",
                                   "--set", f"stages.weights.params.per_batch_seeds={str(per_batch).lower()}",
                                   "--set", f"storage.root={root}", *options, cwd=project, timeout=600))

    # the first run computes its samples in the process that trains (--threads: cv2 used there before the fork)
    runs = {(2, True): train(2, True, "--threads")}
    runs.update({(n, per_batch): train(n, per_batch) for n, per_batch in ((1, True), (0, True), (0, False))})
    sha = {k: run["sha256"] for k, run in runs.items()}
    assert sha[2, True] == sha[1, True] == sha[0, True]  # batch i is seeded (seed, i), whichever process draws it
    assert runs[2, True]["key"] == runs[0, True]["key"]  # workers is a run-time setting: not in the cache key
    assert sha[0, False] != sha[0, True]  # one stream, as the shipped weights were trained


def test_a_killed_training_continues_from_its_checkpoint_to_the_same_weights(project):
    shutil.copytree(project / "storage", project / "other")  # for the uninterrupted run, below
    longer = ("--set", "stages.weights.params.iterations=12", "--set", "stages.weights.params.checkpoint_every=3")
    command = [sys.executable, "-m", "mocapflow.cli.commands", "-v", "train", "--catalog", "catalog.yaml",
               "--out", "killed.pt", *longer]
    process = subprocess.Popen(command, cwd=project, env=env_with_plugins(), stdout=subprocess.DEVNULL,
                               stderr=subprocess.STDOUT)
    try:
        wait_for(lambda: list((project / "storage" / "weights").glob("*/_checkpoint")), timeout=500,
                 what="the training's first checkpoint")
    finally:
        process.kill()
        process.wait()
    assert not (project / "killed.pt").exists()
    resumed = last_json(mocapflow("-v", "train", "--catalog", "catalog.yaml", "--out", "resumed.pt", "--json", *longer,
                                  cwd=project, timeout=600))
    logs = "".join(p.read_text() for p in (project / "storage" / "logs").glob("run-*.log"))
    assert "resuming the training at iteration" in logs
    assert not list((project / "storage" / "weights").glob("*/_checkpoint"))  # dropped by the commit
    whole = last_json(mocapflow("train", "--catalog", "catalog.yaml", "--out", "whole.pt", "--json", *longer,
                                "--set", "storage.root=other", "--set", "stages.weights.params.checkpoint_every=100",
                                cwd=project, timeout=600))
    assert whole["key"] == resumed["key"] and whole["sha256"] == resumed["sha256"]  # as if never killed


def test_a_training_starts_from_a_weights_file_of_its_architecture_and_refuses_another(project):
    shutil.copy(project / "trained.pt", project / "start.pt")  # CATALOG's network: 3 steps from seed 0
    start = torch.load(project / "start.pt", weights_only=True)["state"]
    still = ("--set", "stages.weights.params.learning_rate=1e-12")  # Adam's steps are ~lr: the weights stay put
    tuned = last_json(mocapflow("train", "--catalog", "catalog.yaml", "--out", "tuned.pt", "--json", *still,
                                "--set", "stages.weights.params.init=start.pt", cwd=project, timeout=600))
    scratch = last_json(mocapflow("train", "--catalog", "catalog.yaml", "--out", "scratch.pt", "--json", *still,
                                  cwd=project, timeout=600))
    assert tuned["key"] != scratch["key"]  # the file is part of the key
    ends = {name: torch.load(project / f"{name}.pt", weights_only=True)["state"] for name in ("tuned", "scratch")}
    convs = [k for k, t in start.items() if k.endswith("weight") and t.ndim == 4]
    assert len(convs) > 10
    assert max(float((ends["tuned"][k] - start[k]).abs().max()) for k in convs) < 1e-6  # started from the file
    # and the same steps from a fresh network (seed 0, as the file's) end elsewhere: the file was what was read
    assert max(float((ends["scratch"][k] - start[k]).abs().max()) for k in convs) > 1e-3

    wider = mocapflow("train", "--catalog", "catalog.yaml", "--out", "wider.pt", "--set",
                      "stages.weights.params.init=start.pt", "--set", "stages.weights.params.stream_width=16",
                      cwd=project, check=False, timeout=600)
    assert wider.returncode != 0 and not (project / "wider.pt").exists()
    assert "init weights" in wider.stderr and "stream_width: 8 in the file, 16 here" in wider.stderr


def test_a_network_learns_from_a_teacher_s_maps_of_the_same_grid(project):
    shutil.copy(project / "trained.pt", project / "teacher.pt")  # CATALOG's network: 3 steps from seed 0
    store = Store(load_catalog(project / "catalog.yaml", ()).root)

    def first_loss(*settings: str) -> float:
        run = last_json(mocapflow("train", "--catalog", "catalog.yaml", "--out", "student.pt", "--json",
                                  "--set", "stages.weights.params.init=teacher.pt", *settings, cwd=project, timeout=600))
        return float(store.open("weights", run["key"], get_schema("fcn_weights"))["loss"].values[0])

    truth = first_loss()
    # a student that is the teacher, taught by it alone: its targets are nearly its own maps (batch statistics
    # in training against running ones in the teacher), far nearer than the truth a 3-step network misses
    taught = first_loss("--set", "stages.weights.params.teacher=teacher.pt", "--set", "stages.weights.params.distill=1")
    half = first_loss("--set", "stages.weights.params.teacher=teacher.pt")
    assert taught < 0.5 * half < 0.5 * truth

    other = mocapflow("train", "--catalog", "catalog.yaml", "--out", "small.pt", "--set",
                      "stages.weights.params.teacher=teacher.pt", "--set", "stages.weights.params.input_size=96",
                      cwd=project, check=False, timeout=600)
    assert other.returncode != 0 and "teacher teacher.pt reads 64-pixel crops, this network 96" in other.stderr

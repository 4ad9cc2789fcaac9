"""The suit's CornerdetNet trained through the engine: `mocapflow train` streams the stored crops (StoredSamples)
through the pool, holds one sequence out as the validation split and writes weights the chain's stage reads."""

from __future__ import annotations

import numpy as np
import torch

from conftest import last_json, mocapflow
from mocapflow.pipeline.catalog import load_catalog
from mocapflow.pipeline.plan import build_plan
from mocapflow.pipeline.storage import Store
from mocapflow.schemas import get_schema
from mocapflow.tasks.suit.corners import cornerdet_from_weights

CATALOG = """\
data_roots: [.]
storage: {root: storage/, region_frames: 2}
datasets:
  train:
    kind: studio_suit
    suit: small
    cameras: {count: 2, width: 384, height: 512}
    defaults: {frames: 2}
    sequences:
      sq: {motion: classic_squat, seed: 11}
      jj: {motion: jumping_jack, seed: 12, heading_deg: 90}
stages:
  images: {task: ingest_suit, dataset: train}
  corner_samples:  # the squares are 7-10 px at this size: the usable-corner spacing shrinks with them
    task: corner_training_samples
    inputs: [images]
    params: {capacity: 100, sample: {min_spacing_px: 5}}
  cornerdet:
    task: train_cornerdet
    inputs: [corner_samples]
    params:
      train: {net: {widths: [4, 4, 8, 8], hidden: 8}, iterations: 6, batch: 16}
      stream: {slots: 2, validation: [jj], checkpoint_every: 5}
"""


def test_cornerdet_trains_from_streamed_crops_and_scores_its_validation_sequence(tmp_path):
    (tmp_path / "catalog.yaml").write_text(CATALOG)
    # one worker process renders both takes: the suit's print and body are made once per process, the most of a take
    run = last_json(mocapflow("train", "--catalog", "catalog.yaml", "--stage", "cornerdet", "--out", "det.pt",
                              "--json", "--workers", "1", cwd=tmp_path, timeout=600))
    weights = torch.load(tmp_path / "det.pt", weights_only=True)
    record = weights["training"]
    assert record["images"] == 4 and record["slots"] == 2  # sq's 2 views x 2 frames; jj's held out
    assert record["validation"]["crops"] > 0 and 0 <= record["validation"]["recall"] <= 1
    net = cornerdet_from_weights(weights)  # what find_corners reads
    assert not net.training
    stored = Store(load_catalog(tmp_path / "catalog.yaml").root).open("cornerdet", run["key"],
                                                                      get_schema("suit_net_weights"))
    assert stored.sizes["iteration"] == 6 and np.isfinite(stored["loss"].values).all()
    samples = build_plan(load_catalog(tmp_path / "catalog.yaml")).items["cornerdet/train"].depends_on
    assert sorted(samples) == [f"corner_samples/{s}/cam{v:02d}" for s in ("jj", "sq") for v in (0, 1)]

"""Model weights: hashed into cache keys, loaded once per worker process, plain tensors only."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from conftest import PLUGINS, last_json, mocapflow, read_artifacts
from mocapflow.pipeline import models
from mocapflow.pipeline.catalog import load_catalog
from mocapflow.pipeline.errors import StorageError
from mocapflow.pipeline.execute import run_partition
from mocapflow.pipeline.plan import build_plan


def use_weights(project, gain):
    torch.save({"gain": torch.tensor(float(gain))}, project / "gain.pt")
    text = (project / "catalog.yaml").read_text()
    if "weighted" not in text:
        text = text.replace("task: scale, inputs: [frames], params: {factor: 3, sleep: 0.0}",
                            "task: weighted, inputs: [frames], params: {weights: gain.pt}")
        (project / "catalog.yaml").write_text(text)


def test_changed_weights_recompute_exactly_that_stage_and_downstream(toy_project):
    project = toy_project(frames=8)  # two regions of 4 frames: diffed still reads across a region's edge
    use_weights(project, 2.0)
    first = last_json(mocapflow("run", "--json", cwd=project))
    assert first["failed"] == []
    values = {pid: a for (pid, _), a in read_artifacts(project / "storage").items()}
    raw = {pid: a for pid, a in values.items() if pid.startswith("frames/")}
    np.testing.assert_array_equal(values["scaled/seqA/cam1"]["value"][0], raw["frames/seqA"]["depth"][1] * 2.0)
    assert last_json(mocapflow("run", "--json", cwd=project))["executed"] == []
    use_weights(project, 3.0)
    explained = mocapflow("explain", "scaled", "seqA", "cam0", cwd=project).stdout
    assert "would run" in explained and "weights.weights:" in explained
    again = last_json(mocapflow("run", "--json", cwd=project))
    assert sorted(p.split("/")[0] for p in again["executed"]) == ["diffed"] * 4 + ["scaled"] * 4 + ["summed"] * 2


def test_weights_are_loaded_once_per_process(toy_project, monkeypatch):
    monkeypatch.syspath_prepend(str(PLUGINS))
    project = toy_project()
    use_weights(project, 5.0)
    plan = build_plan(load_catalog(project / "catalog.yaml"))
    before = models.loads
    for pid in ("frames/seqA", "frames/seqB", "scaled/seqA/cam0", "scaled/seqA/cam1", "scaled/seqB/cam0"):
        result = run_partition(plan.items[pid])
        assert result.ok, result.error
    assert models.loads - before == 1


def test_missing_or_unsafe_weights_are_clear_errors(toy_project, tmp_path):
    project = toy_project()
    use_weights(project, 1.0)
    proc = mocapflow("run", "--set", "stages.scaled.params.weights=nowhere.pt", cwd=project, check=False)
    assert proc.returncode == 2 and "weights file" in proc.stderr and "does not exist" in proc.stderr
    torch.save({"gain": np.float64(2.0)}, tmp_path / "pickled.pt")  # a numpy object, not a plain tensor
    with pytest.raises(StorageError, match="must hold plain tensors"):
        from mocapflow.pipeline.hashing import file_digest

        models.load_weights(str(tmp_path / "pickled.pt"), file_digest(str(tmp_path / "pickled.pt")))


def test_a_network_in_another_runtimes_format_arrives_as_its_bytes(tmp_path, monkeypatch):
    from mocapflow.pipeline.hashing import file_digest

    path = tmp_path / "net.tflite"
    data = np.random.default_rng(0).integers(0, 256, 4096, dtype=np.uint8).tobytes()
    path.write_bytes(data)
    assert models.load_weights(str(path), file_digest(str(path))) == data
    with pytest.raises(StorageError, match="changed since the run was planned"):
        models.load_weights(str(path), "0" * 64)
    big = tmp_path / "big.onnx"
    big.write_bytes(data + b"more")
    monkeypatch.setattr(models, "MAX_RAW_BYTES", 4096)
    with pytest.raises(StorageError, match="4,100 bytes, over the 4,096-byte limit"):
        models.load_weights(str(big), file_digest(str(big)))

"""A long task's checkpoint (pipeline/checkpoints.py): kept beside its uncommitted version, read back without
unpickling, refused when damaged or foreign, dropped by the commit."""

import pickle

import pytest
import torch

from mocapflow.pipeline.checkpoints import Checkpoint
from mocapflow.pipeline.errors import StorageError
from mocapflow.pipeline.storage import Store


class Foreign:
    """Not a tensor, number, string or container: loading it would run code."""


def test_a_checkpoint_round_trips_and_belongs_to_its_version(tmp_path):
    store = Store(str(tmp_path / "store"))
    store.begin("weights", "k1", {"partition": "weights/train"})
    checkpoint = Checkpoint(store, "weights", "k1")
    assert checkpoint.load() is None
    checkpoint.save({"iteration": 4, "model": {"w": torch.arange(3.0)}, "rng": '{"state": 1}'})
    again = Checkpoint(store, "weights", "k1").load()
    assert again["iteration"] == 4 and torch.equal(again["model"]["w"], torch.arange(3.0))
    assert Checkpoint(store, "weights", "k2").load() is None  # another cache key: another training
    assert (tmp_path / "store" / "weights" / "k1" / "_checkpoint").is_file()
    assert not list((tmp_path / "store" / "weights" / "k1").glob("*.partial"))


def test_a_pickled_object_or_a_damaged_file_is_refused(tmp_path):
    store = Store(str(tmp_path / "store"))
    store.begin("weights", "k1", {})
    path = tmp_path / "store" / "weights" / "k1" / "_checkpoint"
    path.write_bytes(pickle.dumps({"evil": Foreign()}, protocol=2))
    with pytest.raises(StorageError, match="_checkpoint cannot be read .*delete it to start the training afresh"):
        Checkpoint(store, "weights", "k1").load()
    Checkpoint(store, "weights", "k1").save({"iteration": 1})
    path.write_bytes(path.read_bytes()[:40])
    with pytest.raises(StorageError, match="cannot be read"):
        Checkpoint(store, "weights", "k1").load()
    store.drop_checkpoint("weights", "k1")
    assert not path.exists() and Checkpoint(store, "weights", "k1").load() is None

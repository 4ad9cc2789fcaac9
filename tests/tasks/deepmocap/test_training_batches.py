"""Training batches and checkpoints (tasks/deepmocap/training.py): seeded per batch, so worker processes draw what
one process would; a training stopped after a checkpoint and continued ends with the weights of one that never
stopped."""

import numpy as np
import pytest
import torch
import xarray as xr

from mocapflow.tasks.deepmocap import fcn, training
from mocapflow.tasks.shared.samples import InMemorySamples
from memory_checkpoint import MemoryCheckpoint, Stopped, stopped_and_continued


def _samples(n: int = 5) -> xr.Dataset:
    rng = np.random.default_rng(3)
    uv = rng.uniform(20, 60, (n, 26, 2)).astype(np.float32)
    return xr.Dataset(
        {"depth_image": (("sample", "y", "x", "rgb"), rng.integers(0, 255, (n, 90, 80, 3), dtype=np.uint8)),
         "flow_image": (("sample", "y", "x", "rgb"), rng.integers(0, 255, (n, 90, 80, 3), dtype=np.uint8)),
         "box": (("sample", "corner"), np.tile(np.array([15.0, 10.0, 65.0, 80.0], np.float32), (n, 1))),
         "gt_uv": (("sample", "reflector", "uv"), uv), "gt_uv_prev": (("sample", "reflector", "uv"), uv + 1.0),
         "gt_pixels": (("sample", "reflector"), np.full((n, 26), 9, np.int32))},
        coords={"frame": ("sample", np.arange(n)), "view": ("sample", ["kinect0"] * n)}, attrs={"sample_scale": 0.5})


def _pool(config: training.TrainConfig, n: int = 5) -> training.SamplePool:
    return training.SamplePool(InMemorySamples(_samples(n), training.IMAGES), config)


def test_a_seeded_batch_is_the_same_in_any_order_of_drawing():
    config = training.TrainConfig(input_size=32, batch=3, iterations=6, seed=4, per_batch_seeds=True, workers=2)
    arch = fcn.FcnArchitecture(input_size=32)
    batches = training.SeededBatches(_pool(config), arch, training.CropConfig(), config)
    assert len(batches) == 6
    later, first, again = batches[5], batches[1], batches[1]
    for a, b in zip(first, again):
        np.testing.assert_array_equal(a, b)
    assert not np.array_equal(first[0], later[0])  # another batch, other crops
    depth, flow, s, fields = first
    assert depth.shape == flow.shape == (3, 32, 32, 3) and depth.dtype == np.uint8
    assert s.shape == (3, 27, 8, 8) and fields.shape == (3, 26, 2, 8, 8)
    from_four = training.SeededBatches(_pool(config), arch, training.CropConfig(), config, start=4)
    assert len(from_four) == 2 and all(np.array_equal(a, b) for a, b in zip(from_four[1], later))


def test_the_pool_reads_images_only_for_the_samples_drawn():
    config = training.TrainConfig(frame_step=2)
    reads = []

    class Counting(InMemorySamples):
        def read(self, index, names):
            reads.append(index)
            return super().read(index, names)

    pool = training.SamplePool(Counting(_samples(5), training.IMAGES), config)
    assert len(pool) == 3 and not reads  # frames 0, 2, 4; nothing read yet
    sample = pool[1]
    assert reads == [2] and sample["depth_image"].shape == (90, 80, 3)
    np.testing.assert_array_equal(sample["depth_image"], _samples(5)["depth_image"].values[2])


def test_workers_must_not_be_negative_and_need_per_batch_seeds():
    with pytest.raises(ValueError, match="workers must be >= 0"):
        training.TrainConfig(workers=-1)
    with pytest.raises(ValueError, match="needs per_batch_seeds: true"):
        training.TrainConfig(workers=2)
    with pytest.raises(ValueError, match="checkpoint_every must be >= 1"):
        training.TrainConfig(checkpoint_every=0)


@pytest.mark.parametrize("per_batch_seeds", [False, True])
def test_a_training_stopped_and_continued_ends_with_the_uninterrupted_weights(per_batch_seeds):
    config = training.TrainConfig(input_size=32, stream_width=4, fused_width=4, stage_width=4, stages=2, batch=2,
                                  iterations=7, frame_step=1, checkpoint_every=2, per_batch_seeds=per_batch_seeds,
                                  bfloat16=False)
    torch.set_num_threads(1)
    whole, resumed, at_stop, saves = stopped_and_continued(
        lambda checkpoint: training.train_fcn(_samples(), config, checkpoint=checkpoint), stop_after=2)
    assert at_stop["iteration"] == 4 and len(at_stop["losses"]) == 4
    np.testing.assert_array_equal(resumed["weights"].values, whole["weights"].values)
    np.testing.assert_array_equal(resumed["loss"].values, whole["loss"].values)
    assert saves == 3  # iterations 2 and 4 before the stop, 6 after it; never at the end


def test_a_checkpoint_of_another_schedule_is_refused():
    config = training.TrainConfig(input_size=32, stream_width=4, fused_width=4, stage_width=4, stages=2, batch=2,
                                  iterations=3, frame_step=1, checkpoint_every=1, bfloat16=False)
    checkpoint = MemoryCheckpoint(stop_after=1)
    with pytest.raises(Stopped):
        training.train_fcn(_samples(), config, checkpoint=checkpoint)
    checkpoint.stop_after = None
    longer = training.TrainConfig(**{**config.__dict__, "iterations": 5})
    with pytest.raises(ValueError, match="checkpoint of a 3-iteration training, this one has 5"):
        training.train_fcn(_samples(), longer, checkpoint=checkpoint)

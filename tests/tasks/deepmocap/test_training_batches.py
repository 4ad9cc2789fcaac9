"""Training batches (tasks/deepmocap/training.py): seeded per batch, so worker processes draw what one process would."""

import numpy as np
import pytest

from mocapflow.tasks.deepmocap import fcn, training


def _pool(n: int = 5) -> dict:
    rng = np.random.default_rng(3)
    uv = rng.uniform(20, 60, (n, 26, 2)).astype(np.float32)
    return {"depth_image": rng.integers(0, 255, (n, 90, 80, 3), dtype=np.uint8),
            "flow_image": rng.integers(0, 255, (n, 90, 80, 3), dtype=np.uint8),
            "box": np.tile(np.array([15.0, 10.0, 65.0, 80.0], np.float32), (n, 1)),
            "gt_uv": uv, "gt_uv_prev": uv + 1.0, "gt_pixels": np.full((n, 26), 9, np.int32)}


def test_a_seeded_batch_is_the_same_in_any_order_of_drawing():
    config = training.TrainConfig(input_size=32, batch=3, iterations=6, seed=4, per_batch_seeds=True, workers=2)
    arch = fcn.FcnArchitecture(input_size=32)
    batches = training._SeededBatches(_pool(), arch, training.CropConfig(), config)
    assert len(batches) == 6
    later, first, again = batches[5], batches[1], batches[1]
    for a, b in zip(first, again):
        np.testing.assert_array_equal(a, b)
    assert not np.array_equal(first[0], later[0])  # another batch, other crops
    depth, flow, s, fields = first
    assert depth.shape == flow.shape == (3, 32, 32, 3) and depth.dtype == np.uint8
    assert s.shape == (3, 27, 8, 8) and fields.shape == (3, 26, 2, 8, 8)


def test_workers_must_not_be_negative_and_need_per_batch_seeds():
    with pytest.raises(ValueError, match="workers must be >= 0"):
        training.TrainConfig(workers=-1)
    with pytest.raises(ValueError, match="needs per_batch_seeds: true"):
        training.TrainConfig(workers=2)

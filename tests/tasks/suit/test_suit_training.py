"""The suit's trainings as stages (tasks/suit/training.py): crops streamed through a pool of images, a killed
training continued to the same networks, a validation split scored."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch
import xarray as xr

from mocapflow.tasks.shared.weights import unpack
from mocapflow.tasks.suit import codes as cd
from mocapflow.tasks.suit import corners as co
from mocapflow.tasks.suit import training as tr
from mocapflow.tasks.suit.crop_pool import PoolError
from mocapflow.tasks.suit.net_configs import CodeNetConfig, CornerNetConfig
from memory_checkpoint import stopped_and_continued


def _corner_samples(images=8, capacity=40, seed=0) -> xr.Dataset:
    """As load_samples gives them: (sample, crop, ...) with a sequence per sample; a positive's crop is a bright
    quadrant meeting at its position, a negative's flat."""
    rng = np.random.default_rng(seed)
    present = rng.random((images, capacity)) < 0.4
    position = np.where(present[..., None], rng.uniform(0.2, 0.8, (images, capacity, 2)), 0).astype(np.float32)
    crops = np.full((images, capacity, co.CROP, co.CROP), 60, np.uint8)
    for i, j in zip(*np.nonzero(present)):
        x, y = (co.CELL_LO + position[i, j] * co.CELL).round().astype(int)
        crops[i, j, :y, :x] = crops[i, j, y:, x:] = 200
        position[i, j] = (np.array([x, y]) - 0.5 - co.CELL_LO) / co.CELL  # the corner between pixels x-1 and x
    used = np.ones((images, capacity), bool)
    used[::3, capacity // 2:] = False  # some images have fewer crops (the artifact's padding)
    sequence = np.array([f"s{i % 4}" for i in range(images)], dtype=object)
    return xr.Dataset({"crops": (("sample", "crop", "cy", "cx"), crops), "present": (("sample", "crop"), present),
                       "position": (("sample", "crop", "uv"), position), "used": (("sample", "crop"), used)},
                      coords={"sequence": ("sample", sequence)})


CORNER = tr.TrainCornerdetConfig(
    train=co.TrainConfig(net=CornerNetConfig((4, 4, 4, 4), 4), iterations=7, batch=16),
    stream=tr.StreamConfig(slots=3, checkpoint_every=2, validation=("s3",)), seed=5)


def test_a_cornerdet_training_stopped_and_continued_ends_with_the_uninterrupted_network():
    torch.set_num_threads(1)
    whole, resumed, at_stop, saves = stopped_and_continued(
        lambda checkpoint: tr.train_cornerdet_stage(_corner_samples(), CORNER, checkpoint=checkpoint), stop_after=2)
    assert at_stop["iteration"] == 4 and len(at_stop["resident"]) == 3
    np.testing.assert_array_equal(resumed["weights"].values, whole["weights"].values)
    np.testing.assert_array_equal(resumed["loss"].values, whole["loss"].values)
    assert saves == 3  # iterations 2 and 4 before the stop, 6 after it; never at the end
    record = unpack(whole)["training"]
    assert record["images"] == 6 and record["slots"] == 3  # two of the eight images are the validation's (s3)
    assert record["crops"] == 6 * 40 - 2 * 20  # images 0 and 6 of the six padded (3 of s3 is held out)
    assert whole.sizes["iteration"] == 7 and np.isfinite(whole["loss"].values).all()
    scores = record["validation"]
    assert scores["crops"] == 40 + 20 and 0 <= scores["recall"] <= 1 and 0 <= scores["false_rate"] <= 1


def test_a_cornerdet_trained_through_a_small_pool_learns_what_one_of_every_image_does():
    """The pool changes which crops a batch holds, not what is learnt: trained longer, both find the held-out
    corners."""
    longer = co.TrainConfig(net=CornerNetConfig((8, 8, 16, 16), 16), iterations=600, batch=32, learning_rate=3e-3)
    samples = _corner_samples(images=12, seed=1)
    torch.set_num_threads(1)
    found = {}
    for slots in (4, 12):
        config = tr.TrainCornerdetConfig(train=longer, stream=tr.StreamConfig(slots=slots, validation=("s0",)))
        found[slots] = unpack(tr.train_cornerdet_stage(samples, config))["training"]["validation"]
    for scores in found.values():  # measured: recall 1.0, no false detection, 0.46-0.49 px, for 4 and 12 slots
        assert scores["recall"] > 0.95 and scores["false_rate"] < 0.05 and scores["position_median_px"] < 0.75


def _quad_samples(images=6, capacity=12, seed=0) -> xr.Dataset:
    rng = np.random.default_rng(seed)
    valid = rng.random((images, capacity)) < 0.5
    rotation = np.where(valid, rng.integers(0, 4, (images, capacity)), -1).astype(np.int8)
    code = np.where(valid, rng.integers(0, 625, (images, capacity)), -1).astype(np.int16)
    crops = rng.integers(0, 256, (images, capacity, cd.CROP, cd.CROP), dtype=np.uint8)
    sequence = np.array([f"s{i % 3}" for i in range(images)], dtype=object)
    return xr.Dataset({"crops": (("sample", "crop", "qy", "qx"), crops), "valid": (("sample", "crop"), valid),
                       "rotation": (("sample", "crop"), rotation), "code": (("sample", "crop"), code),
                       "used": (("sample", "crop"), np.ones((images, capacity), bool))},
                      coords={"sequence": ("sample", sequence)})


def test_a_codes_training_stopped_and_continued_ends_with_the_uninterrupted_networks():
    small = CodeNetConfig(widths=(4, 4), hidden=8, pool=8)
    config = tr.TrainCodesConfig(
        train=cd.CodeTrainConfig(rejector=small, recog=small, iterations=5, batch=8, synthetic=16),
        stream=tr.StreamConfig(slots=2, checkpoint_every=2, validation=("s2",)), seed=3)
    torch.set_num_threads(1)
    whole, resumed, at_stop, _ = stopped_and_continued(
        lambda checkpoint: tr.train_codes_stage(_quad_samples(), config, checkpoint=checkpoint), stop_after=1)
    assert {"rejector", "recog", "resident", "numpy_rng", "torch_rng"} <= set(at_stop)
    np.testing.assert_array_equal(resumed["weights"].values, whole["weights"].values)
    record = unpack(whole)["training"]
    assert record["images"] == 4 and record["studio_crops"] == 4 * 12 and record["synthetic_crops"] == 16
    scores = record["validation"]
    assert scores["crops"] == 2 * 12 and 0 <= scores["read_right"] <= scores["rejector_recall"] <= 1


def test_validation_sequences_must_be_some_of_the_training_set():
    for names, what in ((("s9",), "not in the training dataset"), (("s0", "s1", "s2", "s3"), "all of it")):
        config = tr.TrainCornerdetConfig(train=CORNER.train, stream=tr.StreamConfig(validation=names))
        with pytest.raises(PoolError, match=what):
            tr.train_cornerdet_stage(_corner_samples(), config)


def _parameters(weights: dict) -> dict[str, np.ndarray]:
    """The learnt tensors of a weights file (not batch normalisation's running statistics)."""
    return {k: t.numpy() for k, t in weights["state"].items() if not k.endswith(("running_mean", "running_var",
                                                                                  "num_batches_tracked"))}


def test_a_cornerdet_training_from_a_file_starts_from_its_weights():
    torch.set_num_threads(1)
    first = unpack(tr.train_cornerdet_stage(_corner_samples(), CORNER))
    still = dataclasses.replace(CORNER, train=dataclasses.replace(CORNER.train, learning_rate=1e-12),
                                init="first.pt")
    tuned = unpack(tr.train_cornerdet_stage(_corner_samples(seed=1), still, init=first))
    scratch = unpack(tr.train_cornerdet_stage(_corner_samples(seed=1), dataclasses.replace(still, init="")))
    for name, value in _parameters(first).items():
        np.testing.assert_allclose(_parameters(tuned)[name], value, atol=1e-6, err_msg=name)
    assert max(np.abs(_parameters(scratch)[k] - v).max() for k, v in _parameters(first).items()) > 1e-2
    assert tuned["training"]["init"] == "first.pt"
    wider = dataclasses.replace(still, train=dataclasses.replace(still.train, net=CornerNetConfig((4, 4, 4, 8), 4)))
    with pytest.raises(co.CornerError, match=r"widths=\(4, 4, 4, 4\).*widths=\(4, 4, 4, 8\)"):
        tr.train_cornerdet_stage(_corner_samples(), wider, init=first)


def test_a_codes_training_from_a_file_starts_from_its_weights():
    small = CodeNetConfig(widths=(4, 4), hidden=8, pool=8)
    train = cd.CodeTrainConfig(rejector=small, recog=small, iterations=3, batch=8, synthetic=16)
    config = tr.TrainCodesConfig(train=train, stream=tr.StreamConfig(slots=2), seed=3)
    torch.set_num_threads(1)
    first = unpack(tr.train_codes_stage(_quad_samples(), config))
    still = dataclasses.replace(config, train=dataclasses.replace(train, learning_rate=1e-12), init="first.pt")
    tuned = unpack(tr.train_codes_stage(_quad_samples(seed=1), still, init=first))
    for name, value in _parameters(first).items():
        np.testing.assert_allclose(_parameters(tuned)[name], value, atol=1e-6, err_msg=name)
    other = dataclasses.replace(still, train=dataclasses.replace(train, recog=CodeNetConfig((4, 8), 8, 8)))
    with pytest.raises(cd.CodeError, match=r"recog .*widths=\(4, 4\).* in the file"):
        tr.train_codes_stage(_quad_samples(), other, init=first)


def _one(a: np.ndarray) -> np.ndarray:
    """An array of one view and frame: (view, frame, ...)."""
    return a[None, None]


def _board_take(square=24, squares=(6, 7)) -> xr.Dataset:
    """One view and frame of a flat checkerboard with its interior corners as the truth: all visible, the left
    half readable (the right half as a square seen past 70 degrees would be)."""
    ny, nx = squares
    yy, xx = np.mgrid[0:ny * square, 0:nx * square]
    image = np.where((yy // square + xx // square) % 2 == 0, 200, 30).astype(np.uint8)
    image = np.pad(image, 30, constant_values=10)
    gi, gj = np.mgrid[1:nx, 1:ny]
    corners = np.column_stack([gi.ravel(), gj.ravel()]) * square - 0.5 + 30
    readable = corners[:, 0] < image.shape[1] / 2
    return xr.Dataset({"image": (("view", "frame", "y", "x"), _one(image)),
                       "gt_corners2d": (("view", "frame", "corner", "xy"), _one(corners)),
                       "gt_visible": (("view", "frame", "corner"), _one(np.ones(len(corners), bool))),
                       "gt_readable": (("view", "frame", "corner"), _one(readable))},
                      coords={"view": ["cam00"], "frame": [0]})


def test_cornerdet_positives_are_the_readable_corners_or_every_visible_one():
    take = _board_take()
    readable = int(take["gt_readable"].sum())
    sample = co.SampleConfig(per_corner=2, rotate=0.0)
    counts = {}
    for positives in ("readable", "visible"):
        config = tr.CornerSampleStageConfig(sample=sample, positives=positives, capacity=2000, seed=1)
        s = tr.corner_training_samples(take, config)
        counts[positives] = int((s["present"] & s["used"]).sum())
    assert counts == {"readable": 2 * readable, "visible": 2 * take.sizes["corner"]}
    with pytest.raises(co.CornerError, match="'oblique'"):
        tr.CornerSampleStageConfig(positives="oblique")

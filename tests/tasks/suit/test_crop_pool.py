"""The shuffle buffer a suit training streams its crops through: what it holds, what it draws, how it resumes."""

from __future__ import annotations

import numpy as np
import pytest
import xarray as xr

from mocapflow.tasks.shared.samples import InMemorySamples
from mocapflow.tasks.suit.crop_pool import CropPool, PoolError


class _Counted(InMemorySamples):
    """Samples that count their reads (a stand-in for storage)."""

    def __init__(self, ds, streamed):
        super().__init__(ds, streamed)
        self.reads = []

    def read(self, index, names):
        self.reads.append(index)
        return super().read(index, names)


def _samples(n_images=10, capacity=6, seed=0) -> _Counted:
    """Image i's crops are all filled with i (so a drawn crop says where it came from); its first `i % capacity`
    + 1 crops are used, crop 0 is `valid`."""
    crops = np.repeat(np.arange(n_images, dtype=np.uint8), capacity * 4).reshape(n_images, capacity, 2, 2)
    used = np.arange(capacity)[None] <= (np.arange(n_images) % capacity)[:, None]
    valid = np.zeros((n_images, capacity), bool)
    valid[:, 0] = True
    ds = xr.Dataset({"crops": (("sample", "crop", "y", "x"), crops), "used": (("sample", "crop"), used),
                     "valid": (("sample", "crop"), valid),
                     "image": (("sample", "crop"), np.repeat(np.arange(n_images), capacity).reshape(n_images, -1))})
    return _Counted(ds, ("crops",))


def test_a_pool_holds_slots_images_and_over_its_turns_every_image_comes_through():
    samples = _samples()
    pool = CropPool(samples, ("valid", "image"), slots=3)
    rng = np.random.default_rng(1)
    seen = set()
    for _ in range(60):
        pool.turn(rng)
        assert len(set(pool.resident.tolist())) == 3 and pool.held.shape[0] == 3
        batch = pool.draw(rng, 32)
        np.testing.assert_array_equal(batch["crops"][:, 0, 0], batch["image"])  # crops and columns agree
        assert set(batch["image"].tolist()) <= set(pool.resident.tolist())  # only held images are drawn
        seen |= set(batch["image"].tolist())
    assert seen == set(range(10))
    assert len(samples.reads) == 3 + 60  # the first three, then one image read per turn
    assert len(pool) == int(samples.table["used"].values.sum()) and pool.count("valid") == 10


def test_a_pool_of_every_image_draws_uniformly_over_the_used_crops():
    pool = CropPool(_samples(), ("image",), slots=50)
    rng = np.random.default_rng(2)
    pool.turn(rng)
    drawn = np.bincount(pool.draw(rng, 40000)["image"], minlength=10)
    used = pool.used.sum(axis=1)
    np.testing.assert_allclose(drawn / drawn.sum(), used / used.sum(), atol=0.01)
    assert pool.slots == 10


def test_fixed_crops_are_drawn_in_their_share_of_the_whole_set_whatever_the_slots():
    fixed = {"crops": np.full((40, 2, 2), 200, np.uint8), "valid": np.ones(40, bool), "image": np.full(40, -1)}
    for slots in (2, 10):
        pool = CropPool(_samples(), ("valid", "image"), slots=slots, fixed=fixed)
        rng = np.random.default_rng(3)
        pool.turn(rng)
        batch = pool.draw(rng, 20000)
        assert abs((batch["image"] == -1).mean() - 40 / len(pool)) < 0.015  # 40 of 75 crops
        valid = pool.draw(rng, 20000, where="valid")
        assert valid["valid"].all() and abs((valid["image"] == -1).mean() - 40 / 50) < 0.015  # 40 of 50 valid
        assert ((batch["crops"][:, 0, 0] == 200) == (batch["image"] == -1)).all()


def test_a_restored_pool_holds_the_checkpoint_s_images_and_draws_as_the_first_did():
    rng = np.random.default_rng(4)
    first = CropPool(_samples(), ("image",), slots=4)
    for _ in range(5):
        first.turn(rng)
        first.draw(rng, 8)
    state, resident = rng.bit_generator.state, first.resident.tolist()
    again = CropPool(_samples(), ("image",), slots=4)
    again.restore(resident)
    other = np.random.default_rng()
    other.bit_generator.state = state
    for _ in range(5):
        first.turn(rng)
        again.turn(other)
        np.testing.assert_array_equal(first.draw(rng, 8)["image"], again.draw(other, 8)["image"])
    with pytest.raises(PoolError, match="not 4 of the 10 here; delete the checkpoint"):
        again.restore([0, 1, 2])


def test_bad_settings_and_empty_sets_are_refused_by_name():
    with pytest.raises(PoolError, match="slots .0. must be >= 1"):
        CropPool(_samples(), ("image",), slots=0)
    with pytest.raises(PoolError, match="lack position; re-run the samples stage"):
        CropPool(_samples(), ("image", "position"), slots=2)
    pool = CropPool(_samples(), ("image",), slots=2)
    with pytest.raises(PoolError, match="call turn"):
        pool.draw(np.random.default_rng(), 4)

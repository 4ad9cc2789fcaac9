"""The crops a suit training draws its batches from, streamed: a shuffle buffer over the training set's images.

A suit training set is crops cut per image (``suit_corner_samples``: 750 crops of 20 x 20 an image;
``suit_quad_samples``: up to 200 of 104 x 104). The small columns of every crop (whether it holds a corner or a
code, where, which) are in memory for the whole set; the crops themselves are held for ``slots`` images at a time.
Each iteration may swap ``swap`` resident images for others drawn at random, so over a training every image comes
through the buffer while memory holds only ``slots`` of them. With ``slots`` at least the number of images, every
crop is resident and a batch is a uniform draw over the set.

Crops that are not per image (the synthetic crops of every code) can be added as ``fixed``: always resident,
drawn in proportion to their count against the whole set's (so a batch's share of studio crops does not depend on
``slots``).

The pool's state for a checkpoint is the list of resident images (``resident``); a resumed training restores it
(``restore``) and with its generator's state continues as if never stopped.
"""

from __future__ import annotations

from typing import Mapping, Sequence

import numpy as np
import xarray as xr

from mocapflow.tasks.shared.samples import InMemorySamples, Samples

CROPS = "crops"  # the streamed variable of a samples artifact
USED = "used"  # (sample, crop) False past an image's crops


class PoolError(ValueError):
    """A pool that cannot be drawn from: no crops, a column missing, or a bad setting."""


class CropPool:
    """Batches of crops and their columns drawn from ``samples`` (dims ``sample, crop, ...``; ``crops`` read per
    sample) holding ``slots`` samples' crops at a time, plus ``fixed`` crops always held."""

    def __init__(self, samples: Samples, columns: Sequence[str], *, slots: int, swap: int = 1,
                 fixed: Mapping[str, np.ndarray] | None = None):
        if slots < 1 or swap < 0:
            raise PoolError(f"slots ({slots}) must be >= 1 and swap ({swap}) >= 0 images per iteration")
        missing = [name for name in (USED, *columns) if name not in samples.table]
        if missing:
            raise PoolError(f"training samples lack {', '.join(missing)}; re-run the samples stage")
        self.samples, self.columns = samples, tuple(columns)
        self.used = samples.table[USED].values  # (sample, crop)
        self.table = {name: samples.table[name].values for name in self.columns}
        self.n_samples, self.capacity = self.used.shape
        self.slots, self.swap = min(slots, self.n_samples), swap
        self.fixed = None if fixed is None else {name: np.asarray(fixed[name]) for name in (CROPS, *self.columns)}
        self.n_fixed = 0 if self.fixed is None else len(self.fixed[CROPS])
        if not self.used.any() and not self.n_fixed:
            raise PoolError("the training samples hold no crop; check the training dataset")
        self.resident = np.arange(self.slots)  # drawn at the first turn, or a checkpoint's
        self.chosen = self.slots == self.n_samples
        self.held = None  # (slots, capacity, h, w) once the resident samples are read

    @classmethod
    def in_memory(cls, columns: Mapping[str, np.ndarray], **kwargs) -> "CropPool":
        """A pool over crops already in memory (``crops`` and the ``columns``, each (n, ...)): one sample of all."""
        n = len(columns[CROPS])
        ds = xr.Dataset({name: (("sample", "crop", *[f"{name}_{i}" for i in range(1, v.ndim)]), v[None])
                         for name, v in columns.items()})
        ds[USED] = (("sample", "crop"), np.ones((1, n), bool))
        return cls(InMemorySamples(ds, (CROPS,)), [k for k in columns if k != CROPS], slots=1, **kwargs)

    def __len__(self) -> int:
        """Crops in the whole set (every sample's and the fixed ones)."""
        return int(self.used.sum()) + self.n_fixed

    def count(self, where: str | None = None) -> int:
        """Crops in the whole set where column ``where`` is true (all of them for None)."""
        studio = self.used if where is None else self.used & self.table[where].astype(bool)
        fixed = self.n_fixed if where is None or not self.n_fixed else int(self.fixed[where].astype(bool).sum())
        return int(studio.sum()) + fixed

    def restore(self, resident: Sequence[int]) -> None:
        """Hold the samples ``resident`` (a checkpoint's), read anew."""
        resident = np.asarray(resident, np.int64)
        if len(resident) != self.slots or not ((resident >= 0) & (resident < self.n_samples)).all():
            raise PoolError(f"a checkpoint's pool holds samples {resident.tolist()[:8]}..., not {self.slots} of the "
                            f"{self.n_samples} here; delete the checkpoint")
        self.resident, self.held, self.chosen = resident.copy(), None, True

    def turn(self, rng: np.random.Generator) -> None:
        """Before a batch: swap ``swap`` resident samples for others (none while every sample is held); the first
        time, the samples held are drawn (or a checkpoint's restored) and read first."""
        if self.held is None:
            if not self.chosen:
                self.resident, self.chosen = np.sort(rng.choice(self.n_samples, self.slots, replace=False)), True
            self._read_all()
        if self.slots >= self.n_samples:
            return
        for _ in range(self.swap):
            slot = int(rng.integers(self.slots))
            new = int(rng.integers(self.n_samples))
            while new in self.resident:
                new = int(rng.integers(self.n_samples))
            self.resident[slot] = new
            self.held[slot] = self._read(new)

    def draw(self, rng: np.random.Generator, n: int, where: str | None = None) -> dict[str, np.ndarray]:
        """``n`` crops with their columns, uniform over the held ones (where column ``where`` is true); the fixed
        ones drawn in their share of the whole set's. After :meth:`turn`."""
        if self.held is None:
            raise PoolError("draw before the pool's first turn: call turn(rng) before each batch")
        studio = self.used[self.resident]
        if where is not None:
            studio = studio & self.table[where][self.resident].astype(bool)
        flat = np.flatnonzero(studio)  # (slot, crop) flattened
        fixed = np.arange(self.n_fixed) if where is None or not self.n_fixed else np.flatnonzero(self.fixed[where])
        if not len(flat) and not len(fixed):
            raise PoolError(f"no held crop {'is ' + where if where else 'at all'}; check the training samples")
        if not self.n_fixed:
            return self._studio(flat[rng.integers(len(flat), size=n)])
        return self._mixed(rng, n, flat, fixed, self.count(where))

    def _mixed(self, rng: np.random.Generator, n: int, flat: np.ndarray, fixed: np.ndarray, total: int) -> dict:
        """``n`` crops, each held (from ``flat``) with the studio's share of the ``total`` crops, else fixed."""
        from_studio = rng.random(n) < (total - len(fixed)) / total if len(flat) else np.zeros(n, bool)
        studio = self._studio(flat[rng.integers(len(flat), size=int(from_studio.sum()))]) if len(flat) else None
        pick = fixed[rng.integers(len(fixed), size=int((~from_studio).sum()))]
        out = {}
        for name in (CROPS, *self.columns):
            column = np.empty((n, *self.fixed[name].shape[1:]), self.fixed[name].dtype)
            column[~from_studio] = self.fixed[name][pick]
            if studio is not None:
                column[from_studio] = studio[name]
            out[name] = column
        return out

    def _studio(self, flat: np.ndarray) -> dict[str, np.ndarray]:
        slot, crop = np.divmod(flat, self.capacity)
        sample = self.resident[slot]
        return {CROPS: self.held[slot, crop], **{name: self.table[name][sample, crop] for name in self.columns}}

    def _read(self, sample: int) -> np.ndarray:
        return self.samples.read(int(sample), (CROPS,))[CROPS]

    def _read_all(self) -> None:
        first = self._read(self.resident[0])
        self.held = np.empty((self.slots, *first.shape), first.dtype)
        self.held[0] = first
        for slot in range(1, self.slots):
            self.held[slot] = self._read(self.resident[slot])

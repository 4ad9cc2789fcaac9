"""Training samples read one at a time: what a per-dataset task (a training) sees of its inputs.

A training set can be many times the machine's memory (the DeepMoCap set holds both input images of every
view-frame), so a task that declares large variables as streamed gets them through :class:`Samples`: the small
variables of every sample in memory (``table``, dims ``sample, ...``) and the large ones read per sample
(``read``). The engine's implementation reads them from storage chunk by chunk; :class:`InMemorySamples` serves a
loaded dataset (tests, small sets) through the same two calls.
"""

from __future__ import annotations

from typing import Protocol, Sequence

import numpy as np
import xarray as xr


class Samples(Protocol):
    """Every sample's small variables in ``table`` (dims ``sample, ...``, with ``sequence``, ``view`` and ``frame``
    coordinates), its large ones from ``read``."""

    table: xr.Dataset

    def read(self, index: int, names: Sequence[str]) -> dict[str, np.ndarray]:
        """The large variables ``names`` of sample ``index`` (an index along ``table``'s ``sample`` dim)."""
        ...


class InMemorySamples:
    """:class:`Samples` of a dataset already in memory: ``streamed`` are the variables ``read`` serves."""

    def __init__(self, ds: xr.Dataset, streamed: Sequence[str]):
        self.table = ds.drop_vars([name for name in streamed if name in ds.variables])
        self._large = {name: ds[name].values for name in streamed}

    def read(self, index: int, names: Sequence[str]) -> dict[str, np.ndarray]:
        return {name: self._large[name][index] for name in names}


class SampleSubset:
    """:class:`Samples` of ``samples`` at ``index`` only (a split of a training set), in that order."""

    def __init__(self, samples: Samples, index: Sequence[int]):
        self.index = np.asarray(index, np.int64)
        self.table = samples.table.isel(sample=self.index)
        self._samples = samples

    def read(self, index: int, names: Sequence[str]) -> dict[str, np.ndarray]:
        return self._samples.read(int(self.index[index]), names)

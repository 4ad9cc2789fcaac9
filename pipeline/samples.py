"""A per-dataset stage's inputs (a training's): every (sequence, view, frame) of an upstream stage as samples.

Two ways to read them. :func:`load_samples` loads every variable into one dataset with a ``sample`` dim. A task that
declares large variables as streamed (``TaskSpec.streams``) gets :class:`StoredSamples` instead: the small variables
loaded the same way, the large ones read from storage one sample at a time (one chunk), so a training set many
times the machine's memory trains in the memory of its small variables (tasks/shared/samples.py ``Samples``).
"""

from __future__ import annotations

from typing import Sequence

import numpy as np
import xarray as xr

from mocapflow.pipeline.errors import StorageError
from mocapflow.pipeline.storage import Store
from mocapflow.tasks.shared.samples import Samples

SAMPLE_DIMS = ("view", "frame")  # a sample is one view-frame of a sequence, in this order along ``sample``


def select_variables(ds: xr.Dataset, variables, up) -> xr.Dataset:
    """``ds`` with only ``variables`` (None: all), less those that ``up``'s schema marks optional and ``ds`` lacks."""
    if variables is None:
        return ds
    optional = {name for name, spec in up.schema.variables.items() if not spec.required}
    return ds[[v for v in variables if v in ds.variables or v not in optional]]


def load_samples(store: Store, up, variables=None) -> xr.Dataset:
    """A per-dataset stage's input: every (sequence, view, frame) of the upstream as one ``sample`` dim.

    Each sample carries ``sequence``, ``view`` and ``frame`` coordinates; variables without a frame
    dimension (calibration, say) are left out, since samples of different sequences cannot share them.
    The samples are read one partition at a time into arrays sized for all of them, so reading takes the
    memory of the result plus one partition (a training set can be many GB; concatenating loaded parts
    would take twice that).
    """
    parts = _partitions(store, up, variables)
    sizes = [int(np.prod([ds.sizes[d] for d in SAMPLE_DIMS if d in ds.dims])) for _, ds in parts]
    ends = np.cumsum(sizes)
    columns, first = {}, None
    for (sequence, ds), end, size in zip(parts, ends, sizes):
        # loaded before stacking: stacking the lazily indexed zarr arrays reads them point by point (15x slower)
        stacked = ds.load().stack(sample=[d for d in SAMPLE_DIMS if d in ds.dims]).transpose("sample", ...)
        stacked = stacked.reset_index("sample").assign_coords(sequence=("sample", np.full(size, sequence, dtype=object)))
        if first is None:
            first = stacked
            columns = {name: np.empty((int(ends[-1]), *v.shape[1:]), v.dtype)  # (sample, ...) for all the parts
                       for name, v in stacked.variables.items() if v.dims[:1] == ("sample",)}
        for name, column in columns.items():
            column[end - size:end] = stacked.variables[name].values
    if first is None:
        raise StorageError(f"stage {up.stage!r} has no partition to read samples from; run it first")
    sample = {name: (first.variables[name].dims, column, first.variables[name].attrs) for name, column in columns.items()}
    return xr.Dataset({name: sample[name] for name in first.data_vars},
                      coords={**{name: first.coords[name] for name in first.coords if name not in sample},
                              **{name: sample[name] for name in first.coords if name in sample}},
                      attrs=first.attrs)


def samples_input(store: Store, up, variables, streamed: Sequence[str]) -> xr.Dataset | Samples:
    """The input of a per-dataset stage from ``up``: loaded whole, or with ``streamed`` read per sample."""
    if not streamed:
        return load_samples(store, up, variables)
    small = None if variables is None else [v for v in variables if v not in streamed]
    if small is None:
        small = [v for v in up.schema.variables if v not in streamed]
    return StoredSamples(store, up, load_samples(store, up, small), streamed)


class StoredSamples:
    """:class:`~mocapflow.tasks.shared.samples.Samples` of a stored stage: the small variables in ``table``, the
    ``streamed`` ones read from the partitions' zarr arrays when asked (lazily opened: a read touches the chunks
    of that one view-frame). Safe to share with forked worker processes: nothing is read until ``read``."""

    def __init__(self, store: Store, up, table: xr.Dataset, streamed: Sequence[str]):
        self.table, self.streamed = table, tuple(streamed)
        self._parts = [ds[list(self.streamed)] for _, ds in _partitions(store, up, list(self.streamed))]
        self._shapes = [tuple(ds.sizes[d] for d in SAMPLE_DIMS if d in ds.dims) for ds in self._parts]
        self._ends = np.cumsum([int(np.prod(shape)) for shape in self._shapes])
        if int(self._ends[-1]) != table.sizes["sample"]:
            raise StorageError(f"stage {up.stage!r}: {int(self._ends[-1])} samples in its streamed variables but "
                               f"{table.sizes['sample']} in the others; run `mocapflow verify` on it")

    def __len__(self) -> int:
        return int(self._ends[-1])

    def read(self, index: int, names: Sequence[str]) -> dict[str, np.ndarray]:
        if not 0 <= index < len(self):
            raise IndexError(f"sample {index} of {len(self)}")
        part = int(np.searchsorted(self._ends, index, side="right"))
        local = index - (int(self._ends[part - 1]) if part else 0)
        at = dict(zip([d for d in SAMPLE_DIMS if d in self._parts[part].dims], np.unravel_index(local, self._shapes[part])))
        return {name: self._parts[part][name].isel(at).values for name in names}


def _partitions(store: Store, up, variables) -> list[tuple[str, xr.Dataset]]:
    """(sequence, the partition's artifact lazily opened, its per-frame ``variables`` only) of every partition."""
    parts = []
    for sequence, keys in up.by_sequence.items():
        for key in keys.values():
            ds = select_variables(store.open(up.stage, key, up.schema), variables, up)
            parts.append((sequence, ds.drop_vars([n for n, v in ds.data_vars.items() if "frame" not in v.dims])))
    return parts

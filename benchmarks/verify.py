"""Cost of verified artifacts: writing regions while recording each chunk's digest, and reading a version while
checking each chunk against its digest, against the same writes and reads without.

    python benchmarks/verify.py [repeats]        # prints a table and one JSON line

The data is benchmarks/region_write.py's studio-sized take: 3 regions of 16 frames of a 3-view raw sequence
(424x512 uint16 depth and IR, float16 scene flow, bool body mask, float32 2D and 3D ground truth). Write: the
median over every region written (3 per store, ``repeats`` stores per way, the ways interleaved). Read: the median
of loading every variable of a whole store (``repeats`` reads per way, interleaved); both ways must read equal values.
"""

from __future__ import annotations

import json
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import xarray as xr
from region_write import FRAMES, REGION, sequence

from mocapflow.pipeline import storage
from mocapflow.pipeline.integrity import VerifyingStore, Where, zarr_store
from mocapflow.schemas import get_schema


def write(target: str, whole, with_digests: bool) -> tuple[list[float], dict]:
    """Write ``whole`` region by region; each region's seconds and the recorded digests."""
    storage.init_zarr(target, get_schema("raw_sequence"), whole.isel(frame=slice(0, REGION)), FRAMES)
    seconds, digests = [], {}
    for start in range(0, FRAMES, REGION):
        region = whole.isel(frame=slice(start, start + REGION))
        t0 = time.perf_counter()
        storage.write_zarr_region(target, region, start, start + REGION, digests=digests if with_digests else None)
        seconds.append(time.perf_counter() - t0)
    return seconds, digests


def read(target: str, expected: dict | None) -> tuple[float, xr.Dataset]:
    store = target if expected is None else VerifyingStore(zarr_store(target, read_only=True), expected,
                                                           Where("bench", "k", "bench", target))
    t0 = time.perf_counter()
    ds = xr.open_zarr(store, consolidated=False, chunks=None, zarr_format=3).load()
    return time.perf_counter() - t0, ds


def main() -> None:
    repeats = int(sys.argv[1]) if len(sys.argv) > 1 else 5
    whole = sequence(FRAMES)
    writes = {False: [], True: []}
    reads = {False: [], True: []}
    with tempfile.TemporaryDirectory() as tmp:
        for r in range(repeats):
            for way in (False, True):
                seconds, _ = write(str(Path(tmp) / f"{r}-{way}.zarr"), whole, way)
                writes[way].extend(seconds)
        _, expected = write(str(Path(tmp) / "read.zarr"), whole, True)
        target = str(Path(tmp) / "read.zarr")
        for _ in range(repeats):
            for way in (False, True):
                seconds, ds = read(target, expected if way else None)
                reads[way].append(seconds)
                for name in whole.data_vars:
                    np.testing.assert_array_equal(ds[name].values, whole[name].values, err_msg=name)
    out = {"chunks_recorded": len(expected)}
    for what, figures in (("write region", writes), ("read store", reads)):
        plain, verified = statistics.median(figures[False]), statistics.median(figures[True])
        out[what] = {"plain_ms": 1000 * plain, "verified_ms": 1000 * verified, "ratio": verified / plain,
                     "samples": len(figures[True])}
        print(f"{what:14s} plain median {1000 * plain:8.1f} ms  verified median {1000 * verified:8.1f} ms  "
              f"ratio {verified / plain:5.3f}  ({len(figures[True])} each)")
    print(json.dumps(out))


if __name__ == "__main__":
    main()

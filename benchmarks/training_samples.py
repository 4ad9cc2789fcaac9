"""Reading a training set: the seconds and the memory the `weights` stage takes to read its samples.

    mocapflow run --catalog training/catalog_athletic.yaml --until samples    # render it first
    python benchmarks/training_samples.py [--catalog FILE] [--sequences GLOB] [--whole] [--reads N]

Reads the samples of the catalog's training sequences (those matching ``--sequences``, every one by default) the
way the training stage does (pipeline/samples.py): its streamed variables one sample at a time, the rest in memory; ``--whole``
loads every variable, as the stage did before it streamed. Prints one JSON line: partitions, samples, the bytes
held in memory, seconds to open, the median milliseconds of one streamed sample's read (``--reads`` random
samples), and the process's peak resident memory.
"""

from __future__ import annotations

import argparse
import dataclasses
import fnmatch
import json
import resource
import time
from pathlib import Path

import numpy as np

from mocapflow.pipeline.catalog import load_catalog
from mocapflow.pipeline.plan import build_plan
from mocapflow.pipeline.samples import samples_input
from mocapflow.pipeline.storage import Store
from mocapflow.pipeline.training import training_item

ROOT = Path(__file__).resolve().parents[1]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--catalog", default=str(ROOT / "training" / "catalog_athletic.yaml"))
    parser.add_argument("--sequences", default=None, metavar="GLOB", help="only the training sequences whose id matches")
    parser.add_argument("--whole", action="store_true", help="load every variable (no streaming)")
    parser.add_argument("--reads", type=int, default=200, help="random streamed samples to time")
    args = parser.parse_args()
    catalog = load_catalog(args.catalog)
    item = training_item(build_plan(catalog), catalog, None)
    (role, up), = item.upstream.items()
    if args.sequences:
        up = dataclasses.replace(up, by_sequence={s: keys for s, keys in up.by_sequence.items()
                                                  if fnmatch.fnmatchcase(s, args.sequences)})
    streamed = () if args.whole else item.spec.streams.get(role, ())
    started = time.perf_counter()
    samples = samples_input(Store(catalog.root), up, item.spec.reads.get(role), streamed)
    seconds = time.perf_counter() - started
    table = samples if args.whole else samples.table
    read_ms = []
    for index in np.random.default_rng(0).integers(0, table.sizes["sample"], args.reads if streamed else 0):
        t0 = time.perf_counter()
        samples.read(int(index), streamed)
        read_ms.append(1e3 * (time.perf_counter() - t0))
    print(json.dumps({"partitions": sum(len(keys) for keys in up.by_sequence.values()),
                      "samples": table.sizes["sample"], "in_memory_gb": round(table.nbytes / 1e9, 3),
                      "seconds": round(seconds, 2),
                      "read_ms_median": round(float(np.median(read_ms)), 2) if read_ms else None,
                      "peak_rss_gb": round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1e6, 2)}))


if __name__ == "__main__":
    main()

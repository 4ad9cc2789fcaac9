"""Reading a training set: the seconds and the memory the `weights` stage takes to read its samples.

    mocapflow run --catalog training/catalog_athletic.yaml --until samples    # render it first
    python benchmarks/training_samples.py [--catalog FILE] [--sequences N]

Reads the samples of the catalog's first N training sequences (every one by default) the way the training
stage does (pipeline/execute.py), and prints one JSON line: partitions, samples, the bytes read, seconds, and
the process's peak resident memory. Run it under /usr/bin/time -v, or pair two checkouts, to compare codes.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import resource
import time
from pathlib import Path

from mocapflow.pipeline.catalog import load_catalog
from mocapflow.pipeline.execute import _load_samples
from mocapflow.pipeline.plan import build_plan
from mocapflow.pipeline.storage import Store
from mocapflow.pipeline.training import training_item

ROOT = Path(__file__).resolve().parents[1]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--catalog", default=str(ROOT / "training" / "catalog_athletic.yaml"))
    parser.add_argument("--sequences", type=int, default=0, help="the first N training sequences (0: all)")
    args = parser.parse_args()
    catalog = load_catalog(args.catalog)
    item = training_item(build_plan(catalog), catalog, None)
    (role, up), = item.upstream.items()
    if args.sequences:
        up = dataclasses.replace(up, by_sequence=dict(list(up.by_sequence.items())[:args.sequences]))
    started = time.perf_counter()
    samples = _load_samples(Store(catalog.root), up, item.spec.reads.get(role))
    seconds = time.perf_counter() - started
    print(json.dumps({"partitions": sum(len(keys) for keys in up.by_sequence.values()),
                      "samples": samples.sizes["sample"], "gb": round(samples.nbytes / 1e9, 2),
                      "seconds": round(seconds, 2),
                      "peak_rss_gb": round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1e6, 2)}))


if __name__ == "__main__":
    main()

"""What a computed catalog cost, from the engine's records: per stage the worker CPU seconds and the wall seconds
its regions took (each region's marker), summed over partitions, and the total over every stage, the studio's
filming included. For benchmarks/compare.yaml after its run: the CPU total over two cores is the time the
benchmark needs on two cores of its own (the wall clock of a run on a shared machine is not):

    python benchmarks/compare_cost.py --catalog benchmarks/compare.yaml

Prints one JSON object: ``stages`` {stage: {cpu_s, wall_s, partitions}}, ``cpu_s``, ``wall_s`` and
``two_core_minutes`` (cpu_s / 2 / 60). A region written before CPU time was recorded counts its wall seconds.
"""

from __future__ import annotations

import argparse
import json

from mocapflow.pipeline.catalog import load_catalog
from mocapflow.pipeline.plan import build_plan
from mocapflow.pipeline.storage import Store


def costs(catalog_path: str) -> dict:
    catalog = load_catalog(catalog_path)
    store, plan = Store(catalog.root), build_plan(catalog)
    stages: dict[str, dict] = {}
    for item in plan.items.values():
        stage, key = item.partition.stage, item.key
        wall = store.region_seconds(stage, key)
        cpu = store.region_cpu_seconds(stage, key)
        row = stages.setdefault(stage, {"cpu_s": 0.0, "wall_s": 0.0, "partitions": 0})
        row["cpu_s"] += wall if cpu is None else cpu
        row["wall_s"] += wall
        row["partitions"] += 1
    cpu_s = sum(r["cpu_s"] for r in stages.values())
    return {"stages": {s: {k: round(v, 1) for k, v in r.items()} for s, r in stages.items()},
            "cpu_s": round(cpu_s, 1), "wall_s": round(sum(r["wall_s"] for r in stages.values()), 1),
            "two_core_minutes": round(cpu_s / 2 / 60, 1)}


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--catalog", default="benchmarks/compare.yaml")
    print(json.dumps(costs(parser.parse_args().catalog)))

"""Speed of the `refine_reflectors` stage (2D reflectors refined from the solved poses): milliseconds per
view-frame on one CPU core, the stage function called on one frame at a time of every held-out view.
It reads the held-out split's artifacts, so run the evaluation first:

    mocapflow evaluate --catalog benchmarks/catalog.yaml --json
    taskset -c 0 python benchmarks/refine2d.py
"""

from __future__ import annotations

import json
import os
import statistics
import time
from dataclasses import asdict
from pathlib import Path

for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(var, "1")

from mocapflow.pipeline.catalog import load_catalog  # noqa: E402
from mocapflow.pipeline.plan import build_plan  # noqa: E402
from mocapflow.pipeline.storage import Store  # noqa: E402
from mocapflow.schemas import get_schema  # noqa: E402
from mocapflow.tasks.refine2d import Refine2DConfig, refine_reflectors  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
INPUTS = {"reflectors": ("reflectors2d", "reflectors2d"), "poses": ("poses", "poses"), "skeleton": ("skeleton", "skeleton"),
          "masks": ("masks", "reflector_masks"), "frames": ("frames", "raw_sequence")}


def main() -> None:
    catalog = load_catalog(ROOT / "benchmarks" / "catalog.yaml", ())
    plan, store = build_plan(catalog), Store(catalog.root)
    times = []
    for seq in plan.sequences:
        whole = {role: store.open(stage, plan.items[f"{stage}/{seq.id}"].key, get_schema(schema))
                 for role, (stage, schema) in INPUTS.items() if f"{stage}/{seq.id}" in plan.items}
        whole["frames"] = whole["frames"][["depth", "fx", "fy", "cx", "cy", "dist", "cam_to_world"]]
        for view in seq.views:
            view_inputs = dict(whole)
            for role in ("reflectors", "masks"):
                stage, schema = INPUTS[role]
                view_inputs[role] = store.open(stage, plan.items[f"{stage}/{seq.id}/{view}"].key, get_schema(schema))
            view_inputs["frames"] = whole["frames"].sel(view=[view])
            loaded = {role: ds.load() for role, ds in view_inputs.items()}
            for i in range(loaded["reflectors"].sizes["frame"]):
                one = {role: ds.isel(frame=[i]) if "frame" in ds.dims else ds for role, ds in loaded.items()}
                t = time.perf_counter()
                refine_reflectors(**one, **asdict(Refine2DConfig()))
                times.append(1000 * (time.perf_counter() - t))
    print(json.dumps({"refine_reflectors_ms": statistics.median(times), "view_frames": len(times)}))


if __name__ == "__main__":
    main()

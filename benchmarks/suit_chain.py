"""The suit's 2D chain per megapixel on one CPU core: CornerdetNet, candidate quads, RejectorNet and RecogNet, corner
labels and their growth over the grid, on held-out studio images (benchmarks/suit.yaml, which must have run).

    taskset -c 0 python benchmarks/suit_chain.py [--images 8] [--runs 3] [--precision auto]

The networks run as the stages run them (networks.for_inference copies; the code networks in ``--precision``,
ReadConfig's), the labels grow as grow_labels' stage grows them (with CornerdetNet's logits). Prints one JSON line:
the images' size, and per stage and in all the median over images of the fastest of ``runs`` (process CPU time,
so what one core spends whatever else the machine runs) in ms per megapixel, with the counts (detections,
candidate quads, accepted quads, labels, grown labels) per image.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import time
from pathlib import Path

for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(var, "1")

import cv2  # noqa: E402
import numpy as np  # noqa: E402
import torch  # noqa: E402

from mocapflow.pipeline.catalog import load_catalog  # noqa: E402
from mocapflow.pipeline.plan import build_plan  # noqa: E402
from mocapflow.pipeline.storage import Store  # noqa: E402
from mocapflow.tasks.suit import codes as cd  # noqa: E402
from mocapflow.tasks.suit import corners as co  # noqa: E402
from mocapflow.tasks.suit import grow as gr  # noqa: E402
from mocapflow.tasks.suit import labels as lb  # noqa: E402
from mocapflow.tasks.suit import quads as qd  # noqa: E402
from mocapflow.tasks.shared.precision import resolve_precision  # noqa: E402
from mocapflow.tasks.suit.networks import for_inference  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]


def held_out_images(n: int) -> tuple[list[np.ndarray], dict]:
    """``n`` images spread over the held-out takes' views and frames, and the suit's pattern."""
    catalog = load_catalog(ROOT / "benchmarks" / "suit.yaml")
    plan, store = build_plan(catalog), Store(catalog.root)
    out, pattern = [], None
    for seq in plan.sequences:
        ds = plan.open(store, "images", seq.id)
        if pattern is None:
            pattern = {"square_corners": ds["square_corners"].values, "codes": [str(c) for c in ds["code"].values],
                       "n_corners": ds.sizes["corner"], "cells": ds["cells"].values}
        for v in range(0, ds.sizes["view"], 3):
            out.append(ds["image"].values[v, ds.sizes["frame"] // 2])
    step = max(1, len(out) // n)
    return out[::step][:n], pattern


def timed(runs: int, fn, *args):
    """The fastest of ``runs`` calls of fn(*args) in process CPU seconds, and its result."""
    best, result = float("inf"), None
    for _ in range(runs):
        t = time.process_time()
        result = fn(*args)
        best = min(best, time.process_time() - t)
    return best, result


def read(image, xy, quads, rejector, recog, config):
    return cd.read_crops(qd.warp_quads(image, xy[quads]), rejector, recog, config)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--images", type=int, default=8)
    parser.add_argument("--runs", type=int, default=3)
    parser.add_argument("--precision", choices=cd.PRECISIONS, default=cd.ReadConfig().precision)
    args = parser.parse_args()
    torch.set_num_threads(1)
    cv2.setNumThreads(1)
    cornerdet = for_inference(co.cornerdet_from_weights(torch.load(ROOT / "models" / "suit_cornerdet.pt",
                                                                   weights_only=True)))
    rejector, recog = (for_inference(net) for net in
                       cd.nets_from_weights(torch.load(ROOT / "models" / "suit_codes.pt", weights_only=True)))
    read_config = cd.ReadConfig(precision=args.precision)
    images, pattern = held_out_images(args.images)
    square_of_code = {cd.code_index(c): s for s, c in enumerate(pattern["codes"])}
    far = gr.far_corners(pattern["cells"])  # the pattern's, once per suit
    rows = []
    for image in images:
        mp = image.size / 1e6
        t_c, found = timed(args.runs, co.detect_corners, image, cornerdet)
        t_q, quads = timed(args.runs, qd.candidate_quads, image, found.xy)
        t_r, codes = timed(args.runs, read, image, found.xy, quads, rejector, recog, read_config)
        ok = codes.accepted
        t_l, (det, _) = timed(args.runs, lb.corner_labels, quads[ok], codes.rotation[ok], codes.code[ok],
                              codes.confidence[ok], square_of_code, pattern["square_corners"], pattern["n_corners"])
        t_g, grown = timed(args.runs, gr.grow_labels, found.xy, det, pattern["cells"], gr.GrowConfig(), far,
                           found.logit)
        rows.append({"corners": 1000 * t_c / mp, "quads": 1000 * t_q / mp, "codes": 1000 * t_r / mp,
                     "labels": 1000 * t_l / mp, "grow": 1000 * t_g / mp,
                     "all": 1000 * (t_c + t_q + t_r + t_l + t_g) / mp,
                     "n_detections": len(found.xy), "n_quads": len(quads), "n_accepted": int(ok.sum()),
                     "n_labels": int((det >= 0).sum()), "n_grown": int((grown >= 0).sum())})
    out = {"images": len(rows), "megapixels": round(images[0].size / 1e6, 2),
           "precision": resolve_precision(args.precision)}
    out.update({f"{k}_ms_per_mp" if not k.startswith("n_") else k: round(statistics.median(r[k] for r in rows), 1)
                for k in rows[0]})
    print(json.dumps(out))


if __name__ == "__main__":
    main()

"""Where the suit's 2D chain loses corners: readable ones (a coded square of them seen whole within 70 degrees of
face-on) against those seen obliquely (visible, not readable), on a run catalog's stored takes.

    mocapflow run --catalog benchmarks/suit_networks_tuning.yaml
    python benchmarks/suit_oblique.py [--catalog benchmarks/suit_networks_tuning.yaml] [--set KEY=VALUE ...]

Per kind of corner, over every view and frame: how many the truth shows, the share CornerdetNet finds within 1.5 px,
the share found with a presence logit of at least 3 (what ``grow_labels`` takes), the share the final labels
(``grow_labels``) name right (within 2 px), and the share found, not labelled right, with a grid neighbour labelled
(what growing could still reach). Prints one JSON line.
"""

from __future__ import annotations

import argparse
import json
import sys

import numpy as np
from scipy.spatial import cKDTree

from mocapflow.pipeline.catalog import load_catalog
from mocapflow.pipeline.plan import build_plan
from mocapflow.pipeline.storage import Store
from mocapflow.tasks.suit.grow import GrowConfig, cell_edges
from suit_verify_tune import stage_of

FOUND_PX, RIGHT_PX = 1.5, 2.0


def image_counts(truth, visible, readable, detections, logits, labels, edges) -> dict[str, np.ndarray]:
    """One image's counts per kind: shown, found, found with logit >= min_logit, labelled right, reachable."""
    ok = np.isfinite(detections).all(axis=1)
    detections, logits = detections[ok], logits[ok]
    if len(detections):
        dist, nearest = cKDTree(detections).query(np.nan_to_num(truth, nan=-1e9))
        found, strong = dist <= FOUND_PX, (dist <= FOUND_PX) & (logits[nearest] >= GrowConfig().min_logit)
    else:
        found = strong = np.zeros(len(truth), bool)
    right = np.linalg.norm(labels - truth, axis=1) <= RIGHT_PX
    labelled = np.isfinite(labels).all(axis=1)
    beside = np.zeros(len(truth), bool)
    beside[edges[:, 0]] |= labelled[edges[:, 1]]
    beside[edges[:, 1]] |= labelled[edges[:, 0]]
    return {kind: np.array([m.sum(), (m & found).sum(), (m & strong).sum(), (m & right).sum(),
                            (m & found & ~right & beside).sum()])
            for kind, m in (("readable", visible & readable), ("oblique", visible & ~readable))}


def counts(catalog) -> dict[str, np.ndarray]:
    store, plan = Store(catalog.root), build_plan(catalog, None)
    names = {t: stage_of(catalog, t) for t in ("ingest_suit", "find_corners", "grow_labels")}
    total = {"readable": np.zeros(5), "oblique": np.zeros(5)}
    edges = None
    for seq in plan.sequences:
        images = plan.open(store, names["ingest_suit"], seq.id).sel(view=list(seq.views)).load()
        edges = np.array(list(cell_edges(images["cells"].values))) if edges is None else edges
        for v, view in enumerate(seq.views):
            corners = plan.open(store, names["find_corners"], seq.id, view).sel(view=view).load()
            grown = plan.open(store, names["grow_labels"], seq.id, view).sel(view=view).load()
            for f in range(images.sizes["frame"]):
                got = image_counts(images["gt_corners2d"].values[v, f], images["gt_visible"].values[v, f],
                                   images["gt_readable"].values[v, f],
                                   np.column_stack([corners["x"].values[f], corners["y"].values[f]]),
                                   corners["logit"].values[f],
                                   np.column_stack([grown["x"].values[f], grown["y"].values[f]]), edges)
                for kind, c in got.items():
                    total[kind] += c
    return total


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--catalog", default="benchmarks/suit_networks_tuning.yaml")
    parser.add_argument("--set", dest="sets", action="append", default=[], metavar="KEY=VALUE")
    args = parser.parse_args()
    total = counts(load_catalog(args.catalog, tuple(args.sets)))
    out = {kind: {"corners": int(c[0]), "found": c[1] / c[0], "found_logit3": c[2] / c[0], "labelled_right": c[3] / c[0],
                  "found_unlabelled_beside_a_label": c[4] / c[0]} for kind, c in total.items()}
    json.dump(out, sys.stdout)
    sys.stdout.write("\n")


if __name__ == "__main__":
    main()

"""Decide whether retrained networks replace the shipped ones in the suit's 2D chain, on the tuning split
(benchmarks/suit_networks_tuning.yaml: training takes, never the held-out splits).

    mocapflow train --catalog training/suit_long.yaml --stage cornerdet --out models/suit_cornerdet_visible.pt
    mocapflow train --catalog training/suit_long.yaml --stage codes --out models/suit_codes_long.pt
    mocapflow run --catalog benchmarks/suit_networks_tuning.yaml
    python benchmarks/suit_networks_tune.py [--cornerdet FILE] [--codes FILE]

The choice it printed (docs/suit.md) made the retrained code networks the shipped ones (models/suit_codes.pt) with
acceptance 2; to decide again, put the former networks back in models/suit_codes.pt (the file's history) and the
retrained ones in models/suit_codes_long.pt. The retrained CornerdetNet, not chosen, ships beside the other as
models/suit_cornerdet_visible.pt.

Runs the catalog's chain (find_corners, find_quads, read_codes, label_corners, grow_labels) with each pair of
networks, the shipped or the retrained CornerdetNet with the shipped or the retrained code networks, each pair with
RejectorNet's acceptance (``ReadConfig.accept``, a logit) at each of ``ACCEPT``, and scores it with ``mocapflow
evaluate --json``: readable corners labelled right, visible corners labelled right, wrong labels.

The rule, fixed before any figure was seen: a point is eligible when its share of wrong labels is at most the
shipped chain's (both shipped networks, acceptance 0) and it labels at least the shipped chain's readable corners
right, less ``READABLE_SLACK`` (0.5) percentage points. Of the eligible points, the one labelling the most visible
corners right (the readable ones are among them); ties by fewer retrained networks, then the lower acceptance.
Prints one JSON line: every point's figures and the choice.

The acceptance joined the grid after a first pass without it: the retrained code networks read more squares but
accepted more that the truth calls misread or hidden (wrong labels as read 15 -> 36 of about 16,000), so no pair
was eligible at acceptance 0.
"""

from __future__ import annotations

import argparse
import itertools
import json
import subprocess
import sys

READABLE_SLACK = 0.5  # readable corners labelled right a retrained network may cost, percentage points
ACCEPT = (0.0, 2.0, 3.0)  # RejectorNet logits tried (0: probability 1/2, the shipped setting)
KEYS = ("suit_detect_rate", "suit_visible_rate", "suit_wrong_labels", "suit_wrong_label_rate")


def overrides(cornerdet: str, codes: str, accept: float) -> list[str]:
    """The catalog settings that run the chain with these networks ("" the shipped one) and acceptance."""
    out = ["--set", f"stages.codes.params.read.accept={accept}"]
    for stage, weights in (("corners", cornerdet), ("codes", codes)):
        if weights:
            out += ["--set", f"stages.{stage}.params.weights={weights}"]
    return out


def scored(catalog: str, cornerdet: str, codes: str, accept: float) -> dict:
    """The chain with these networks and acceptance, run (cached stages reused) and evaluated."""
    sets = overrides(cornerdet, codes, accept)
    subprocess.run(["mocapflow", "run", "--catalog", catalog, "--no-progress", *sets], check=True,
                   stdout=subprocess.DEVNULL)
    out = subprocess.run(["mocapflow", "evaluate", "--catalog", catalog, "--json", *sets], check=True,
                         capture_output=True, text=True).stdout
    figures = json.loads(out.strip().splitlines()[-1])
    return {"cornerdet": cornerdet or "shipped", "codes": codes or "shipped", "accept": accept,
            **{k: figures[k] for k in KEYS}}


def choose(points: list[dict]) -> dict:
    """The rule of the module's docstring; ``points[0]`` is the shipped chain."""
    shipped = points[0]
    eligible = [p for p in points if p["suit_wrong_label_rate"] <= shipped["suit_wrong_label_rate"]
                and p["suit_detect_rate"] >= shipped["suit_detect_rate"] - READABLE_SLACK / 100]
    return max(eligible, key=lambda p: (p["suit_visible_rate"], -retrained(p), -p["accept"]))


def retrained(point: dict) -> int:
    """How many of a pair's networks are retrained ones."""
    return (point["cornerdet"] != "shipped") + (point["codes"] != "shipped")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--catalog", default="benchmarks/suit_networks_tuning.yaml")
    parser.add_argument("--cornerdet", default="../models/suit_cornerdet_visible.pt",
                        help="the retrained CornerdetNet, as the catalog resolves it")
    parser.add_argument("--codes", default="../models/suit_codes_long.pt",
                        help="the retrained code networks, as the catalog resolves them")
    args = parser.parse_args()
    points = [scored(args.catalog, det, codes, accept) for accept, det, codes in
              itertools.product(ACCEPT, ("", args.cornerdet), ("", args.codes))]
    json.dump({"points": points, "choice": choose(points)}, sys.stdout)
    sys.stdout.write("\n")


if __name__ == "__main__":
    main()

"""Regenerate the comparison's section of docs/results.md and its summary row from the computed comparison, and the
comparison page's figures under docs/compare/: one command for the page and the rows.

    python docs/make_compare_section.py [NOTE]   # runs `mocapflow compare --catalog benchmarks/compare.yaml`

NOTE: a sentence on the run's wall clock, put in the section as it is.

The section lies between the markers ``<!-- compare:begin -->`` and ``<!-- compare:end -->`` of docs/results.md; the
summary row is the one starting ``| one performance``.
"""

from __future__ import annotations

import datetime
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

from mocapflow.pipeline.catalog import load_catalog
from mocapflow.pipeline.compare import BODY_PARTS, compare_plan
from mocapflow.pipeline.plan import build_plan
from mocapflow.pipeline.storage import Store

ROOT = Path(__file__).resolve().parents[1]
CATALOG = ROOT / "benchmarks" / "compare.yaml"
RESULTS = ROOT / "docs" / "results.md"
BEGIN, END = "<!-- compare:begin -->", "<!-- compare:end -->"
SYSTEMS = {  # how each is filmed and configured, and which body it fits
    "deepmocap": "DeepMoCap (3 IR-depth sensors, 26 reflectors; the default network, regions of a real Kinect's size, "
                 "rings rolled 3°; Anny fitted to the reflectors)",
    "uuo": "UUO (40 unlabelled markers hidden by the body, broken and ghosting; BlazePose's estimate from the take's "
           "video as the prior; Anny)",
    "suit": "suit (8 grey cameras, the sewn medium print; grown labels, a calibration 0.25 px off; Anny for the holes)",
    "markerless": "markerless peer (5 grey cameras, BlazePose 2D keypoints, Pose2Sim's triangulation; no body model)",
}
FITS_ANNY = {"deepmocap", "uuo", "suit"}
FIGURES = ("compare_parts.png", "compare_error_walk_b.png")  # of the page's figures, those docs/results.md shows


def _num(v, fmt="{:.1f}") -> str:
    return "-" if v is None or not np.isfinite(v) else fmt.format(v)


def section(result: dict, wall_note: str) -> str:
    systems = result["systems"]
    head = ("| system | MPJPE mm (takes median / p90) | " + " | ".join(BODY_PARTS) +
            " | surface mm | complete | CPU s per captured s |")
    rows = [head, "|" + "---|" * (7 + len(BODY_PARTS) - 2)]
    for s in systems:
        o = result["overall"][s]
        rows.append(f"| {SYSTEMS.get(s, s)} | {_num(o['mpjpe_mm'])} ({_num(o['take_median_mm'])} / "
                    f"{_num(o['take_p90_mm'])}) | " + " | ".join(_num(o["parts_mm"][p]) for p in BODY_PARTS) +
                    f" | {_num(o['surface_mm'])} | {o['completeness']:.0%} | {_num(o['cpu_s_per_s'])} |")
    takes = "; ".join(f"{take} " + " / ".join(_num(t["systems"][s]["mpjpe_mm"]) for s in systems)
                      for take, t in result["takes"].items())
    gap = max(t["truth_gap_mm"] for t in result["takes"].values())
    anny = ", ".join(s for s in systems if s in FITS_ANNY)
    return "\n".join([
        f"`python docs/make_compare_section.py` (runs `mocapflow compare --catalog benchmarks/compare.yaml --json "
        f"--out compare-page`; {datetime.date.today():%Y-%m-%d}, 2-core Intel Xeon with AMX): held-out CMU squats, walk and jumping "
        f"jacks, subjects seeds 9401 and 9402, six 2 s takes on the mesh body, every system in its realistic default "
        f"configuration (nothing made from the truth reaches any), scored on the same {sum(len(t['times']) for t in result['takes'].values())} "
        f"instants against one truth: the systems' truths there agree within {gap:.2f} mm. {wall_note}",
        "",
        *rows,
        "",
        f"Per take MPJPE ({' / '.join(systems)}, mm): {takes}. CPU seconds are each region's worker CPU time as the "
        "engine records it, the studio's filming left out.",
        "",
        "What each is best and worst at, on these takes (computed from the table):",
        *_best_and_worst(result),
        "",
        f"**Bodies, said plainly.** {anny} fit Anny, the studio's own body model: the body the truth is made of, so "
        "their fits start from the right bones, the right joint places inside the body and (for UUO and the suit) "
        "places on its very skin. A real person is not Anny: the joints' places inside a body differ by a centimetre "
        "or two between body models, which these figures do not pay. The markerless peer fits no body (its joints are "
        "BlazePose's landmarks mapped to the template's) and is filmed in grey with the suit printed on the body (the "
        "studio films no colour from a camera ring yet): a pessimistic bound for a colour markerless system.",
    ])


def _best_and_worst(result: dict) -> list[str]:
    lines = []
    for s in result["systems"]:
        o = result["overall"][s]
        parts = {p: v for p, v in o["parts_mm"].items() if np.isfinite(v)}
        takes = {t: r["systems"][s]["mpjpe_mm"] for t, r in result["takes"].items()}
        best_part, worst_part = min(parts, key=parts.get), max(parts, key=parts.get)
        best_take, worst_take = min(takes, key=takes.get), max(takes, key=takes.get)
        lines.append(f"- **{s}**: best on the {best_part} ({parts[best_part]:.1f} mm), worst on the {worst_part} "
                     f"({parts[worst_part]:.1f} mm); takes from {takes[best_take]:.1f} mm ({best_take}) to "
                     f"{takes[worst_take]:.1f} mm ({worst_take}); {o['cpu_s_per_s']:.1f} CPU s per captured s; "
                     f"needs: " + "; ".join(f"{k} {v}" for k, v in o["needs"].items()) + ".")
    return lines


def summary_row(result: dict) -> str:
    systems = result["systems"]
    mpjpe = " / ".join(_num(result["overall"][s]["mpjpe_mm"]) for s in systems)
    cost = " / ".join(_num(result["overall"][s]["cpu_s_per_s"]) for s in systems)
    return (f"| one performance, {len(systems)} systems (6 held-out takes, same truth frames, realistic defaults): "
            f"MPJPE {' / '.join(systems)}; CPU s per captured s | {mpjpe} mm; {cost} | (measured, no goal) | "
            "`python docs/make_compare_section.py` ([below](#one-performance-three-systems-and-the-markerless-peer)) |")


def main() -> None:
    with tempfile.TemporaryDirectory() as tmp:
        subprocess.run([sys.executable, "-m", "mocapflow.cli.commands", "compare", "--catalog", str(CATALOG),
                        "--out", tmp], check=True, cwd=ROOT / "benchmarks")
        for name in FIGURES:
            shutil.copy(Path(tmp) / name, ROOT / "docs" / "compare" / name)
    catalog = load_catalog(str(CATALOG), ())
    result = compare_plan(catalog, build_plan(catalog), Store(catalog.root))
    wall = sys.argv[1] if len(sys.argv) > 1 else ""
    text = RESULTS.read_text()
    a, b = text.index(BEGIN) + len(BEGIN), text.index(END)
    text = text[:a] + "\n" + section(result, wall) + "\n" + text[b:]
    lines = [summary_row(result) if line.startswith("| one performance") else line for line in text.splitlines()]
    RESULTS.write_text("\n".join(lines) + "\n")


if __name__ == "__main__":
    main()

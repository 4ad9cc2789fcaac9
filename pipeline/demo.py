"""`mocapflow demo`: the whole system on a small embedded dataset, with its accuracy and a report.

Writes ``<out>/catalog.yaml`` (3 views, a few of the studio's procedural exercises, a few seconds
each), runs every stage through the engine with the shipped FCN weights, evaluates the solved poses
against the studio's ground truth, and writes BVH and C3D files and ``report/report.html``. The
catalog is rewritten only when the options change, so a second run is served from the cache.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from mocapflow.pipeline.catalog import load_catalog
from mocapflow.pipeline.errors import InputError
from mocapflow.pipeline.scaffold import DEFAULT_STAGES

DEFAULT_MOTIONS = ("jumping_jack", "classic_squat", "elbow_flexion")


@dataclass(frozen=True)
class DemoOptions:
    motions: tuple[str, ...] = DEFAULT_MOTIONS
    frames: int = 90  # 3 s at 30 fps
    views: int = 3
    seed: int = 1


def catalog_text(options: DemoOptions) -> str:
    from mocapflow.tasks.studio.motion import EXERCISES

    unknown = [m for m in options.motions if m not in EXERCISES]
    if unknown:
        raise InputError(f"demo motions {unknown} are not studio exercises; choose from {sorted(EXERCISES)}")
    if options.frames < 30:
        raise InputError(f"--frames {options.frames} is too short to calibrate a skeleton; use 30 or more")
    sequences = "".join(f"      {m}_s{options.seed + k}: {{motion: {m}, seed: {options.seed + k}}}\n"
                        for k, m in enumerate(options.motions))
    return ("# Written by `mocapflow demo`; rewritten when its options change.\n"
            "data_roots: [.]\n"
            "storage:\n  root: storage/\n  region_frames: 32\n"
            "datasets:\n  recordings:\n    kind: studio\n"
            f"    defaults: {{frames: {options.frames}, fps: 30.0, views: {options.views}, noise: 1.0}}\n"
            f"    sequences:\n{sequences}"
            + DEFAULT_STAGES
            + "evaluation:\n  sequences: \"*\"\n")


def prepare(out: Path, options: DemoOptions):
    """The demo catalog in ``out`` (written when missing or different), loaded."""
    out.mkdir(parents=True, exist_ok=True)
    path = out / "catalog.yaml"
    text = catalog_text(options)
    if not path.exists() or path.read_text() != text:
        path.write_text(text)
    return load_catalog(str(path), ())

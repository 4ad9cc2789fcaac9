"""`mocapflow demo`: the whole system on a small embedded dataset, with its accuracy and a report.

Writes ``<out>/catalog.yaml`` (3 views, a few of the studio's procedural exercises, a few seconds
each), runs every stage through the engine with the shipped FCN weights, evaluates the solved poses
against the studio's ground truth, and writes BVH and C3D files and ``report/report.html``. The
catalog is rewritten only when the options change, so a second run is served from the cache.
"""

from __future__ import annotations

import os
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

from mocapflow.cli.scaffold import DEFAULT_STAGES
from mocapflow.pipeline.catalog import load_catalog
from mocapflow.pipeline.errors import InputError, StorageError
from mocapflow.pipeline.evaluate import evaluate, headline, table
from mocapflow.pipeline.export import export_files
from mocapflow.pipeline.plan import build_plan
from mocapflow.pipeline.report import build_report
from mocapflow.pipeline.scheduler import compute_missing
from mocapflow.pipeline.storage import Store
from mocapflow.tasks.studio.motion import EXERCISES

DEFAULT_MOTIONS = ("jumping_jack", "classic_squat", "elbow_flexion")


@dataclass(frozen=True)
class DemoOptions:
    motions: tuple[str, ...] = DEFAULT_MOTIONS
    frames: int = 90  # 3 s at 30 fps
    views: int = 3
    seed: int = 1


def catalog_text(options: DemoOptions) -> str:
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
    """The demo catalog in ``out`` (written when missing or different), loaded; the options are checked before
    any folder is made."""
    text = catalog_text(options)
    _check_writable(out)
    out.mkdir(parents=True, exist_ok=True)
    path = out / "catalog.yaml"
    if not path.exists() or path.read_text() != text:
        path.write_text(text)
    return load_catalog(str(path), ())


def _check_writable(out: Path) -> None:
    """Refuse an ``out`` folder this process cannot write (the demo writes its cache, exports and report there)."""
    existing = out.absolute()
    while not existing.exists() and existing.parent != existing:
        existing = existing.parent
    if not os.access(existing, os.W_OK):
        raise StorageError(f"--out {out}: cannot write in {existing} (read-only, or not writable by this user); "
                           "choose a writable --out folder")


def run_demo(out: Path, options: DemoOptions, *, workers: int, processes: bool = True,
             log: Callable[[Store], str] | None = None,
             report: Callable[[str], None] | None = None) -> tuple[str, dict, list[Path]]:
    """Run, evaluate, export and report the demo; return the accuracy table, the summary figures and
    the files written. ``log``: starts the run's log file in the demo's store, returns its path (the summary's
    "log"); ``report``: a line per finished stage (scheduler.run_items)."""
    started = time.perf_counter()
    catalog = prepare(out, options)
    store = Store(catalog.root)
    log_path = log(store) if log is not None else None
    plan = build_plan(catalog, None)
    computed = compute_missing(plan.items.values(), store, workers=workers, processes=processes,
                               what="the demo failed", report=report)
    result = evaluate(catalog, plan, store)
    text = table(result)
    files = [path for fmt in ("bvh", "c3d")
             for path in export_files(catalog, None, fmt, None, out / "export", workers, processes=processes,
                                          force=True)]  # the demo's own files, rewritten
    page, images, _ = build_report(catalog, plan, store, out / "report", title="mocapflow demo",
                                   summary={"partitions computed": len(computed)}, files=files,
                                   result=result)
    summary = {**headline(result), "partitions computed": len(computed),
               "seconds": round(time.perf_counter() - started, 1), **({"log": log_path} if log_path else {})}
    return text, summary, files + images + [page]

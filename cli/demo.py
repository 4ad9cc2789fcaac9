"""`mocapflow demo`: each capture system on a small studio take of the mesh body, with its accuracy and a report.

``--system deepmocap`` (the default), ``uuo``, ``suit`` or ``all``. Each writes ``<out>/catalog.yaml`` (a tiny
studio take on the Anny mesh body, filmed the system's way), runs every stage through the engine with the
shipped weights, evaluates the result against the studio's ground truth, writes the system's files under
``<out>/export/`` and its report page, ``<out>/report/report.html``. ``all`` runs the three in turn, each in
``<out>/<system>/``. The catalog is rewritten only when the options change, so a second run is served from the
cache.

- DeepMoCap: three IR-depth sensors film one exercise (reflectors on the skin); the chain of catalog.yaml, Anny
  fitted to the reflectors; BVH and C3D.
- UUO: 40 unlabelled markers on the whole body and a simulated monocular prior (the ``mild`` form: smooth joint
  errors, any facing, drift); the four best facings solved with lighter settings than the benchmarks', the most
  plausible kept; labelled C3D and BVH. One second of one take with light settings: its figures show the chain
  at work, not the system's accuracy (docs/uuo.md; measured 166 mm MPJPE here, facing right).
- The suit: six grey cameras of the real size (1536 x 2048, about a pixel per millimetre on the body) film two
  frames at 5 fps; the 2D chain with the shipped networks, triangulation and filling; labelled corners (C3D) and
  the filled suit per frame (PLY).
"""

from __future__ import annotations

import os
import tempfile
import time
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Callable

from mocapflow.cli.scaffold import DEFAULT_STAGES
from mocapflow.pipeline.catalog import load_catalog
from mocapflow.pipeline.errors import InputError, StorageError
from mocapflow.pipeline.evaluate import evaluate
from mocapflow.pipeline.export import export_files
from mocapflow.pipeline.plan import build_plan
from mocapflow.pipeline.scheduler import compute_missing
from mocapflow.pipeline.storage import Store
from mocapflow.presentation.evaluate import headline, table
from mocapflow.presentation.report import build_report
from mocapflow.tasks.studio.motion import EXERCISES

SYSTEMS = ("deepmocap", "uuo", "suit")
CHOICES = SYSTEMS + ("all",)


@dataclass(frozen=True)
class SystemDemo:
    """What one system's demo films and writes: its default motions and frames, the fewest frames its stages
    accept, the frame rate, and the export formats."""

    motions: tuple[str, ...]
    frames: int
    min_frames: int
    fps: float
    exports: tuple[str, ...]
    why_min: str


DEMOS = {
    "deepmocap": SystemDemo(("jumping_jack",), 45, 30, 30.0, ("bvh", "c3d"),
                            "too short to calibrate a skeleton"),
    "uuo": SystemDemo(("side_reaches",), 30, 15, 30.0, ("c3d", "bvh"),
                      "too short to group the markers by the bone they ride"),
    "suit": SystemDemo(("classic_squat",), 2, 2, 5.0, ("c3d", "ply"),
                       "too short for the filling's temporal term"),
}
DEFAULT_MOTIONS = DEMOS["deepmocap"].motions  # kept for callers of the DeepMoCap-only demo


@dataclass(frozen=True)
class DemoOptions:
    """``motions`` and ``frames``: empty / None take the system's defaults (DEMOS)."""

    motions: tuple[str, ...] = ()
    frames: int | None = None
    views: int = 3
    seed: int = 1
    system: str = "deepmocap"

    def resolved(self) -> "DemoOptions":
        """The options with the system's defaults filled in, checked."""
        if self.system not in SYSTEMS:
            raise InputError(f"demo system {self.system!r} is not one of {list(CHOICES)}")
        demo = DEMOS[self.system]
        motions = tuple(self.motions) or demo.motions
        frames = demo.frames if self.frames is None else int(self.frames)
        unknown = [m for m in motions if m not in EXERCISES]
        if unknown:
            raise InputError(f"demo motions {unknown} are not studio exercises; choose from {sorted(EXERCISES)}")
        if frames < demo.min_frames:
            raise InputError(f"--frames {frames} is {demo.why_min} ({self.system}); use {demo.min_frames} or more")
        return replace(self, motions=motions, frames=frames)


def systems_of(choice: str) -> tuple[str, ...]:
    """The systems a ``--system`` choice runs, in order."""
    if choice not in CHOICES:
        raise InputError(f"--system {choice!r} is not one of {list(CHOICES)}")
    return SYSTEMS if choice == "all" else (choice,)


def folders(out: Path, choice: str) -> dict[str, Path]:
    """Where each system's demo writes: ``out`` itself for one system, ``out/<system>`` for each with ``all``."""
    return {s: (out / s if choice == "all" else out) for s in systems_of(choice)}


def _sequences(options: DemoOptions, indent: str = "      ") -> str:
    return "".join(f"{indent}{m}_s{options.seed + k}: {{motion: {m}, seed: {options.seed + k}}}\n"
                   for k, m in enumerate(options.motions))


HEAD = "data_roots: [.]\nstorage:\n  root: storage/\n  region_frames: {region}\n"


def catalog_text(options: DemoOptions) -> str:
    """The demo catalog of ``options.system`` (its defaults filled in)."""
    o = options.resolved()
    intro = f"# Written by `mocapflow demo --system {o.system}`; rewritten when its options change.\n"
    if o.system == "deepmocap":
        return (intro + HEAD.format(region=32)
                + "datasets:\n  recordings:\n    kind: studio\n"
                f"    defaults: {{frames: {o.frames}, fps: 30.0, views: {o.views}, noise: 1.0, body: mesh}}\n"
                f"    sequences:\n{_sequences(o)}"
                + DEFAULT_STAGES
                + "evaluation:\n  sequences: \"*\"\n")
    if o.system == "uuo":
        return (intro + HEAD.format(region=o.frames)
                + "datasets:\n  markers:\n    kind: studio_markers\n"
                f"    defaults: {{frames: {o.frames}, fps: 30.0, views: 1}}\n"
                "    markers: {count: 40, part: body, dropout: 0.002}   # occlusion, breaks, ghosts: the studio's\n"
                f"    sequences:\n{_sequences(o)}"
                "stages:\n"
                "  markers: {task: ingest_markers, dataset: markers}     # unlabelled trajectories\n"
                "  segments: {task: rigid_segments, inputs: [markers]}   # markers grouped by the bone they ride\n"
                "  prior:     # a monocular body as a video estimator gives it: smooth joint errors, any facing, drift\n"
                f"    {{task: simulated_prior, inputs: [markers], params: {{form: mild, seed: {o.seed}}}}}\n"
                "  screen:    # placements of the prior from every root yaw 30 deg apart, mirrored too\n"
                "    task: screen_hypotheses\n    inputs: [markers, segments, prior]\n"
                "    params: {matching: {frames: 12, iterations: 12}}\n"
                "  h0:        # the four best placements solved; settings lighter than the benchmarks' to stay short\n"
                "    task: solve_screened\n    inputs: [markers, segments, prior, screen]\n"
                "    params:\n      rank: 0\n      solve: &fast\n        matching: {frames: 12, iterations: 12}\n"
                "        pose_fit: {rounds: 3, iterations: 10}\n        ik: {iterations: 40}\n"
                + "".join(f"  h{r}: {{task: solve_screened, inputs: [markers, segments, prior, screen], "
                          f"params: {{rank: {r}, solve: *fast}}}}\n" for r in range(1, 4))
                + "  body:      # the most plausible solve, refined: body parts, vertices, inverse kinematics\n"
                "    task: best_hypothesis\n    inputs: {markers: markers, h0: h0, h1: h1, h2: h2, h3: h3}\n"
                "    params: {ik: {iterations: 40}}\n"
                "evaluation:\n  sequences: \"*\"\n")
    return (intro + HEAD.format(region=4)
            + "datasets:\n  suit:\n    kind: studio_suit\n    suit: medium\n"
            "    cameras: {count: 6, width: 1536, height: 2048, radius: 3.0}   # about a pixel per mm on the body\n"
            f"    defaults: {{frames: {o.frames}, fps: {DEMOS['suit'].fps}, start_s: 0.5}}\n"
            f"    sequences:\n{_sequences(o)}"
            "stages:\n"
            "  images: {task: ingest_suit, dataset: suit}\n"
            "  corners: {task: find_corners, inputs: [images]}                       # CornerdetNet\n"
            "  quads: {task: find_quads, inputs: {images: images, corners: corners}}\n"
            "  codes: {task: read_codes, inputs: {images: images, corners: corners, quads: quads}}  # RejectorNet, "
            "RecogNet\n"
            "  labels: {task: label_corners, inputs: {images: images, corners: corners, quads: quads, codes: codes}}\n"
            "  grown: {task: grow_labels, inputs: {images: images, corners: corners, labels: labels}}\n"
            "  points: {task: triangulate_corners, inputs: {labels: grown, images: images}}\n"
            "  filled: {task: fill_suit, inputs: {points: points, images: images}}   # the holes filled\n"
            "evaluation:\n  sequences: \"*\"\n")


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


def demo_plan(options: DemoOptions) -> dict:
    """What a demo films and runs, without running or writing anything: the system, its takes (motion, frames,
    fps), each stage's partition count in plan order, the partitions in all and the export formats."""
    o = options.resolved()
    with tempfile.TemporaryDirectory() as scratch:
        path = Path(scratch) / "catalog.yaml"
        path.write_text(catalog_text(o))
        plan = build_plan(load_catalog(str(path), ()), None)
    return {"system": o.system, "takes": {f"{m}_s{o.seed + k}": m for k, m in enumerate(o.motions)},
            "frames": o.frames, "fps": DEMOS[o.system].fps,
            "stages": {stage: len(items) for stage, items in plan.by_stage().items()},
            "partitions": len(plan.items), "exports": list(DEMOS[o.system].exports)}


def describe_demo(out: Path, options: DemoOptions) -> str:
    """The plan of a demo as lines for the console (`mocapflow demo --plan`)."""
    p = demo_plan(options)
    takes = ", ".join(f"{t} ({m})" for t, m in p["takes"].items())
    stages = ", ".join(f"{s} {n}" for s, n in p["stages"].items())
    return (f"{p['system']}: {takes}, {p['frames']} frames at {p['fps']:g} fps on the mesh body, into {out}/\n"
            f"  {p['partitions']} partitions: {stages}\n"
            f"  then: evaluate against the studio's truth, export {' and '.join(p['exports'])} to {out / 'export'}/, "
            f"report {out / 'report' / 'report.html'}")


TITLES = {"deepmocap": "DeepMoCap: IR-depth sensors and reflectors", "uuo": "UUO: unlabelled markers anywhere",
          "suit": "the checkerboard suit: dense labelled corners"}


def run_demo(out: Path, options: DemoOptions, *, workers: int, processes: bool = True,
             log: Callable[[Store], str] | None = None,
             report: Callable[[str], None] | None = None) -> tuple[str, dict, list[Path]]:
    """Run, evaluate, export and report one system's demo; return the accuracy table, the summary figures and
    the files written. ``log``: starts the run's log file in the demo's store, returns its path (the summary's
    "log"); ``report``: a line per finished stage (scheduler.run_items)."""
    started = time.perf_counter()
    system = options.resolved().system
    catalog = prepare(out, options)
    store = Store(catalog.root)
    log_path = log(store) if log is not None else None
    plan = build_plan(catalog, None)
    computed = compute_missing(plan.items.values(), store, workers=workers, processes=processes,
                               what=f"the {system} demo failed", report=report)
    result = evaluate(catalog, plan, store)
    text = table(result)
    files = [path for fmt in DEMOS[system].exports
             for path in export_files(catalog, None, fmt, None, out / "export", workers, processes=processes,
                                      force=True)]  # the demo's own files, rewritten
    page, images, _ = build_report(catalog, plan, store, out / "report", title=f"mocapflow demo: {TITLES[system]}",
                                   summary={"partitions computed": len(computed)}, files=files, result=result)
    summary = {"system": system, **headline(result), "partitions computed": len(computed),
               "seconds": round(time.perf_counter() - started, 1), **({"log": log_path} if log_path else {})}
    return text, summary, files + images + [page]

"""The `mocapflow` command line."""

from __future__ import annotations

import contextlib
import hashlib
import json
import logging
import sys
import time
from pathlib import Path

import click

from mocapflow.cli.demo import CHOICES as DEMO_CHOICES
from mocapflow.cli.demo import DemoOptions, describe_demo, run_demo
from mocapflow.cli.demo import folders as demo_folders
from mocapflow.cli.scaffold import scaffold
from mocapflow.formats.calibration import read_calibration, write_calibration
from mocapflow.pipeline.catalog import load_catalog
from mocapflow.pipeline.compare import compare_plan
from mocapflow.pipeline.errors import MocapflowError, PlanError
from mocapflow.pipeline.evaluate import evaluate as run_evaluation
from mocapflow.pipeline.evaluate import evaluation_plan
from mocapflow.pipeline.export import export_files
from mocapflow.pipeline.plan import Partition, Plan, WorkItem, build_plan, held_versions, select, status
from mocapflow.pipeline.registry import commands as system_commands
from mocapflow.pipeline.registry import did_you_mean
from mocapflow.pipeline.runlog import run_log
from mocapflow.pipeline.scheduler import check_address, compute_missing, failure_report, run_items
from mocapflow.pipeline.storage import Store
from mocapflow.pipeline.training import export_weights, training_item
from mocapflow.presentation.compare import headline as compare_headline
from mocapflow.presentation.compare import table as compare_table
from mocapflow.presentation.compare import write_compare_page
from mocapflow.presentation.evaluate import headline, table
from mocapflow.presentation.report import build_report

catalog_option = click.option("--catalog", "catalog_path", default="catalog.yaml", show_default=True,
                              type=click.Path(dir_okay=False), help="catalog file")
set_option = click.option("--set", "overrides", multiple=True, metavar="KEY=VALUE",
                          help="override a catalog value, e.g. --set stages.flow.task=dis (repeatable)")
sequences_option = click.option("--sequences", default=None, metavar="GLOB", help="only sequences whose id matches")
workers_option = click.option("--workers", default=2, show_default=True, type=click.IntRange(min=1),
                              help="local worker processes, one task at a time each")
threads_option = click.option("--threads", is_flag=True,
                              help="run the local workers as threads of this process: they start sooner, but the "
                                   "Python-heavy stages then wait on each other (one GIL)")


class _Group(click.Group):
    """The engine's commands, then those the registered systems add (``System.commands``), loaded only when the
    command line lists them or is asked for one it does not have itself."""

    def list_commands(self, ctx):
        try:
            added = system_commands()
        except MocapflowError as exc:  # a broken plug-in must not hide the engine's own commands
            logging.getLogger(__name__).warning("the systems' commands are not listed: %s", exc)
            added = {}
        return sorted({*super().list_commands(ctx), *added})

    def get_command(self, ctx, name):
        own = super().get_command(ctx, name)
        if own is not None:
            return own
        found = system_commands().get(name)
        return found[1].load() if found is not None else None

    def invoke(self, ctx):
        try:
            return super().invoke(ctx)
        except MocapflowError as exc:
            click.echo(f"error: {exc}", err=True)
            sys.exit(2)


@click.group(cls=_Group)
@click.option("-v", "--verbose", count=True, help="more log output (-v info, -vv debug)")
def main(verbose: int) -> None:
    """mocapflow: optical motion capture as a cached, resumable dataflow."""
    level = [logging.WARNING, logging.INFO, logging.DEBUG][min(verbose, 2)]
    root = logging.getLogger()
    before = list(root.handlers)
    logging.basicConfig(level=level, format="%(levelname)s %(name)s: %(message)s")
    for handler in root.handlers:
        if handler not in before:  # the console's; a run's log file takes INFO whatever it shows
            handler.setLevel(level)


def _run_log(store: Store, command: str) -> str:
    """Log the command's run to a file in the storage root until it returns; the file's path."""
    return click.get_current_context().with_resource(run_log(store, command))


def _log_said(log_path: str | None, store: Store) -> str:
    """Where the run's log is, for the console's last line."""
    return f"log {log_path}" if log_path else f"no log (the storage root {store.root} is read-only)"


def _stage_lines():
    """Where stdout is not a terminal (a pipe, a CI log), a line per finished stage, else nothing."""
    return None if sys.stdout.isatty() else click.echo


@main.command()
@catalog_option
@set_option
@sequences_option
@click.option("--only", default=None, metavar="STAGE", help="run this stage only (its inputs must exist)")
@click.option("--until", default=None, metavar="STAGE", help="run this stage and everything it needs")
@click.option("--dry-run", is_flag=True, help="print the plan (stage x partition) and exit")
@workers_option
@threads_option
@click.option("--scheduler", "address", default=None, metavar="ADDRESS",
              help="run on an existing dask.distributed scheduler, e.g. tcp://10.0.0.5:8786")
@click.option("--keep-going", is_flag=True, help="continue past failed partitions")
@click.option("--json", "as_json", is_flag=True, help="print a JSON summary as the last line of stdout")
@click.option("--no-progress", is_flag=True, help="hide the progress bar")
def run(catalog_path, overrides, sequences, only, until, dry_run, workers, threads, address, keep_going, as_json,
        no_progress):
    """Run the catalog's stages, reusing every cached partition."""
    started = time.perf_counter()
    if address:
        check_address(address)  # before the run's lease writes into the store
    catalog = load_catalog(catalog_path, overrides)
    store = Store(catalog.root)
    plan = build_plan(catalog, sequences)
    items = select(plan, catalog, store, only=only, until=until)
    run_id = None
    if not dry_run and store.writable():  # held until the command ends: gc deletes nothing this run reads or writes
        run_id = click.get_current_context().with_resource(store.run_lease(f"run {catalog_path}", held_versions(items)))
    cached = [i for i in items if store.is_complete(i.partition.stage, i.key)]
    todo = [i for i in items if i not in cached]
    if not dry_run and todo and run_id is None:  # a read-only store: only a run served from its cache reports
        raise store.refuse_writes(f"{len(todo)} partition(s) are to be computed, e.g. {todo[0].partition.id}")
    if dry_run:
        cells = {i.partition.id: ("cached" if i in cached else "run") for i in items}
        click.echo(_matrix(plan, [s for s in catalog.stages if any(i.partition.stage == s for i in items)], cells))
        click.echo(f"{len(todo)} to run, {len(cached)} cached")
        if as_json:
            click.echo(json.dumps({"planned": [i.partition.id for i in todo], "cached": [i.partition.id for i in cached]}))
        return
    log_path = _run_log(store, "run")
    results = run_items(todo, workers=workers, processes=not threads, address=address, keep_going=keep_going,
                        progress=not no_progress and sys.stderr.isatty(), report=_stage_lines(), run_id=run_id)
    by_status = {s: [r for r in results if r.status == s] for s in ("executed", "cached", "failed", "skipped")}
    elapsed = time.perf_counter() - started
    found_complete = len(by_status["cached"])  # complete when a worker reached them (another run wrote them)
    summary = (f"{len(by_status['executed'])} executed, {len(cached) + found_complete} cached, "
               f"{len(by_status['failed'])} failed, {len(by_status['skipped'])} skipped in {elapsed:.2f} s")
    logging.getLogger(__name__).info("%s", summary)
    click.echo(f"{summary}; {_log_said(log_path, store)}")
    for r in by_status["failed"] + by_status["skipped"]:  # the log holds every one, root failures first
        logging.getLogger(__name__).info("%s %s: %s", r.status.upper(), r.partition, r.error)
        if r.detail:
            logging.getLogger(__name__).info("%s", r.detail)
    for line in failure_report(results):
        click.echo(line, err=True)
    if as_json:
        click.echo(json.dumps({
            "executed": [r.partition for r in by_status["executed"]],
            "cached": [i.partition.id for i in cached] + [r.partition for r in by_status["cached"]],
            "failed": [r.partition for r in by_status["failed"]],
            "skipped": [r.partition for r in by_status["skipped"]],
            "errors": {r.partition: r.error for r in by_status["failed"]},
            "regions": {r.partition: r.regions for r in by_status["executed"]},
            "seconds": round(elapsed, 3),
        }))
    if by_status["failed"] or by_status["skipped"]:
        sys.exit(1)


@main.command("status")
@catalog_option
@set_option
@sequences_option
def status_cmd(catalog_path, overrides, sequences):
    """fresh / damaged / partial / stale / missing for every stage x partition."""
    catalog = load_catalog(catalog_path, overrides)
    store = Store(catalog.root)
    plan = build_plan(catalog, sequences)
    versions = {stage: store.versions(stage) for stage in catalog.stages}
    cells = {pid: status(item, store, versions) for pid, item in plan.items.items()}
    click.echo(_matrix(plan, list(catalog.stages), cells))
    counts = {s: list(cells.values()).count(s) for s in ("fresh", "damaged", "partial", "stale", "missing")}
    click.echo(", ".join(f"{n} {s}" for s, n in counts.items()))


@main.command()
@catalog_option
@set_option
@click.argument("stage", required=False)
def verify(catalog_path, overrides, stage):
    """Check every complete version (of STAGE, or of every stage) against the digests recorded when it was written;
    damaged ones are marked, and the next `mocapflow run` writes exactly their damaged regions again."""
    catalog = load_catalog(catalog_path, overrides)
    store = Store(catalog.root)
    stages = store.stages_on_disk()
    if stage is not None and stage not in stages:
        known = sorted(set(catalog.stages) | set(stages))
        raise MocapflowError(f"no stored versions of stage {stage!r} in {catalog.root}; stages: {', '.join(known)}")
    counts = {"intact": 0, "damaged": 0, "unverified": 0}
    for name in [stage] if stage else stages:
        for version in store.versions(name):
            if version.complete:
                counts[_verify_version(store, version)] += 1
    click.echo(f"{counts['intact']} intact, {counts['damaged']} damaged, {counts['unverified']} unverified "
               "(written before digests were recorded)")
    if counts["damaged"]:
        click.echo("run `mocapflow run` to recompute the damaged regions", err=True)
        sys.exit(1)


def _verify_version(store: Store, version) -> str:
    """Check one complete version, mark it if damaged; intact, damaged or unverified."""
    damage = store.verify(version.stage, version.key)
    if damage is None:
        return "unverified"
    if not damage:
        return "intact"
    chunks = {d.chunk: d.problem for d in damage}
    click.echo(f"DAMAGED {version.partition} ({version.stage}/{version.key}): {len(chunks)} chunk(s), in "
               f"{', '.join(sorted({d.group for d in damage}))}")
    for chunk, problem in chunks.items():
        click.echo(f"  {chunk} {problem}")
    store.mark_damaged(version.stage, version.key, damage, f"verify {version.partition}")
    return "damaged"


@main.command()
@catalog_option
@set_option
@click.argument("stage")
@click.argument("sequence")
@click.argument("view", required=False)
def explain(catalog_path, overrides, stage, sequence, view):
    """Why STAGE of SEQUENCE [VIEW] would run: which key component changed, old vs new."""
    catalog = load_catalog(catalog_path, overrides)
    store = Store(catalog.root)
    plan = build_plan(catalog)
    click.echo(_explain(_explained_item(catalog, plan, stage, sequence, view), store))


def _explained_item(catalog, plan: Plan, stage: str, sequence: str, view: str | None) -> WorkItem:
    """The work item `explain STAGE SEQUENCE [VIEW]` names; an unknown name is refused with the nearest known one."""
    if stage not in catalog.stages:
        raise PlanError(f"explain: no stage {stage!r}{did_you_mean(stage, catalog.stages)}; "
                        f"stages: {list(catalog.stages)}")
    partition = catalog.stages[stage].spec.partition
    names = sorted(plan.dataset_of.values() if partition == "dataset" else plan.dataset_of)
    what = "dataset" if partition == "dataset" else "sequence"
    if sequence not in names:
        raise PlanError(f"explain: no {what} {sequence!r}{did_you_mean(sequence, names)}; {what}s: {names}")
    if partition == "view":
        views = list(next(s for s in plan.sequences if s.id == sequence).views)
        if view is None:
            raise PlanError(f"explain: stage {stage!r} runs per view; add the VIEW argument, one of {views}")
        if view not in views:
            raise PlanError(f"explain: sequence {sequence!r} has no view {view!r}{did_you_mean(view, views)}; "
                            f"its views: {views}")
    elif view is not None:
        raise PlanError(f"explain: stage {stage!r} runs per {partition}; drop the VIEW argument {view!r}")
    pid = Partition(stage, sequence, view if partition == "view" else None).id
    if pid not in plan.items:
        raise PlanError(f"explain: stage {stage!r} does not run on {sequence!r}: it reads another dataset "
                        f"(`mocapflow status` lists its partitions)")
    return plan.items[pid]


def _explain(item: WorkItem, store: Store) -> str:
    stage = item.partition.stage
    if store.is_complete(stage, item.key):
        return f"{item.partition.id} is fresh (key {item.key}); nothing would run"
    done = store.regions_done(stage, item.key)
    if done:
        return (f"{item.partition.id} is partial: {done} region(s) of key {item.key} are written, the rest are not; "
                "a run resumes it at the first missing region")
    versions = [v for v in store.versions(stage) if v.partition == item.partition.id]
    if any(v.key == item.key for v in versions):
        return f"{item.partition.id} was started (key {item.key}) but no region was written; it would run"
    others = [v for v in versions if v.key != item.key]
    if not others:
        return f"{item.partition.id} was never computed (key {item.key}); it would run"
    prev = max(others, key=lambda v: (v.complete, v.lineage.get("finished") or v.lineage.get("started") or ""))
    lines = [f"{item.partition.id} would run: key {prev.key} -> {item.key} "
             f"(previous version {'complete' if prev.complete else 'incomplete'}, "
             f"finished {prev.lineage.get('finished', '-')})"]
    hinted = set()
    for path, old, new in _diff(prev.lineage.get("components", {}), json.loads(json.dumps(dict(item.components)))):
        lines.append(f"  {path}: {json.dumps(old)} -> {json.dumps(new)}")
        role = path.split(".")[1] if path.startswith("upstream.") else None
        if role in item.upstream and role not in hinted:
            hinted.add(role)
            up = item.upstream[role]
            lines.append(f"    upstream stage {up.stage!r} changed; see `mocapflow explain {up.stage} "
                         f"{item.partition.sequence}{' ' + item.partition.view if up.partition == 'view' else ''}`")
    return "\n".join(lines)


def _diff(old, new, prefix=""):
    if isinstance(old, dict) and isinstance(new, dict):
        for key in sorted(set(old) | set(new)):
            yield from _diff(old.get(key), new.get(key), f"{prefix}.{key}" if prefix else key)
    elif old != new:
        yield prefix, old, new


@main.command()
@catalog_option
@set_option
@click.option("--dry-run", is_flag=True, help="list what would be deleted")
def gc(catalog_path, overrides, dry_run):
    """Delete stored versions that the current catalog no longer references, except those a live run holds."""
    catalog = load_catalog(catalog_path, overrides)
    store = Store(catalog.root)
    plan = build_plan(catalog)
    keep = {(i.partition.stage, i.key) for i in plan.items.values()}
    with store.run_lease(f"gc {catalog_path}", [], kind="gc"):  # runs starting now wait until it ends
        doomed = [v for stage in store.stages_on_disk() for v in store.versions(stage) if (v.stage, v.key) not in keep]
        held = store.held_versions()
        deleted, kept = 0, 0
        for v in doomed:
            why = held.get((v.stage, v.key)) or (None if dry_run else _gc_delete(store, v))
            if why is None:
                deleted += 1
                click.echo(f"{'would delete' if dry_run else 'deleted'} {v.stage}/{v.key} ({v.partition})")
            else:
                kept += 1
                click.echo(f"{'would keep' if dry_run else 'kept'} {v.stage}/{v.key} ({v.partition}): in use by {why}")
    click.echo(f"{deleted} unreferenced version(s) {'to delete' if dry_run else 'deleted'}, {kept} kept because a "
               f"live run holds them, {len(keep)} referenced by the catalog")


def _gc_delete(store: Store, v) -> str | None:
    """Delete an unreferenced version unless a run holds it (asked again under its lock); None when deleted, else
    what holds it."""
    try:
        with store.lock(v.stage, v.key, f"gc {v.partition}"):
            held = store.held_versions().get((v.stage, v.key))
            if held is not None:
                return held
            store.remove_version(v.stage, v.key)
    except MocapflowError as exc:
        return f"a lock: {exc}"
    return None


@main.command()
@click.argument("folder", type=click.Path(file_okay=False))
@click.option("--force", is_flag=True, help="overwrite an existing catalog.yaml")
def init(folder, force):
    """Scaffold a catalog.yaml for a FOLDER of recordings: C3D/TRC marker files (UUO), DeepMoCap dataset takes,
    raw zarr stores or depth-and-IR PNG folders (DeepMoCap), suit images with a calibration (a studio rehearsal: the
    suit reads no recorded images yet)."""
    made = scaffold(Path(folder), force=force)
    for note in made.notes:
        click.echo(f"note: {note}", err=True)
    click.echo(f"wrote {made.path} ({made.kind}); check it with `mocapflow run --catalog {made.path} --dry-run`, "
               f"run it with `mocapflow run --catalog {made.path}` and see it with "
               f"`mocapflow report --catalog {made.path} --out {Path(folder) / 'report'}`")


@main.group()
def calibration():
    """Camera calibrations from other systems."""


@calibration.command("import")
@click.argument("files", nargs=-1, required=True, type=click.Path(dir_okay=False))
@click.option("--format", "fmt", required=True, type=click.Choice(["qca", "toml", "opencv"]),
              help="qca: Qualisys .qca(.txt); toml: anipose/Pose2Sim Calib.toml; opencv: a cv2.FileStorage YAML/XML "
                   "file of one camera (named by the file)")
@click.option("--unit", type=click.Choice(["mm", "m"]), default=None,
              help="length unit of the file's positions/translations [qca: mm; toml: m; opencv: required]")
@click.option("--up", type=click.Choice(["y", "z"]), default="z", show_default=True,
              help="the file's up axis (y: turned onto the project's Z up)")
@click.option("--fps", required=True, type=float, help="the recordings' frame rate (calibration.yaml needs it)")
@click.option("--out", required=True, type=click.Path(dir_okay=False), help="the calibration.yaml to write")
@click.option("--force", is_flag=True, help="overwrite an existing --out")
def import_calibration(files, fmt, unit, up, fps, out, force):
    """Write the cameras of FILES (one or more, their views merged) as the project's calibration.yaml."""
    views: dict = {}
    for file in files:
        for name, values in read_calibration(Path(file), fmt, unit=unit, up=up).items():
            if name in views:
                raise MocapflowError(f"{file}: camera {name!r} is also in an earlier file; give every camera its "
                                     "own name")
            views[name] = values
    path = write_calibration(Path(out), views, fps, force=force)
    click.echo(f"wrote {path}: {len(views)} view(s) {', '.join(views)}")


@main.command()
@click.option("--catalog", "catalog_path", required=True, type=click.Path(dir_okay=False),
              help="training catalog (a system's training stage per dataset)")
@set_option
@sequences_option
@click.option("--stage", default=None, help="the training stage [the catalog's one stage run per dataset]")
@click.option("--out", required=True, type=click.Path(dir_okay=False), help="weights file to write")
@workers_option
@threads_option
@click.option("--json", "as_json", is_flag=True, help="print a JSON summary as the last line of stdout")
def train(catalog_path, overrides, sequences, stage, out, workers, threads, as_json):
    """Train the catalog's network (seeded) and write its weights; every step is a cached stage."""
    started = time.perf_counter()
    catalog = load_catalog(catalog_path, overrides)
    store = Store(catalog.root)
    plan = build_plan(catalog, sequences)
    item = training_item(plan, catalog, stage)
    log_path = _run_log(store, "train")
    inputs = [i for i in select(plan, catalog, store, only=None, until=item.partition.stage)
              if i.partition.id != item.partition.id]
    compute_missing(inputs, store, workers=workers, processes=not threads, what="training failed")
    # the training itself in this process (it takes every core anyway): its progress reaches the console and the log
    compute_missing([item], store, workers=1, processes=False, what="training failed")
    data = export_weights(store, item, Path(out))
    sha = hashlib.sha256(data).hexdigest()
    click.echo(f"wrote {out} ({len(data) / 1e6:.2f} MB, sha256 {sha[:16]}) from {item.partition.id} "
               f"(key {item.key[:12]}) in {time.perf_counter() - started:.1f} s; {_log_said(log_path, store)}")
    if as_json:
        click.echo(json.dumps({"weights": str(out), "sha256": sha, "bytes": len(data), "key": item.key,
                               "seconds": round(time.perf_counter() - started, 3)}))


@main.command()
@catalog_option
@set_option
@sequences_option
@click.option("--format", "fmt", default="c3d", show_default=True,
              help="a format a system exports: c3d/trc labelled 3D markers; bvh the solved poses; for the suit: c3d "
                   "its labelled corners, ply the filled suit mesh per frame; for a UUO solve: c3d its markers "
                   "labelled by body part and vertex, bvh the solved rig, report a page of figures; a plug-in "
                   "system's own")
@click.option("--stage", default=None,
              help="the stage to export [c3d/trc: the last smoothed stage, else markers3d, else the UUO solve; bvh: "
                   "the poses stage, else the UUO solve; report: the UUO solve]")
@click.option("--out", "out_dir", required=True, type=click.Path(file_okay=False), help="folder for <sequence>.<format>")
@click.option("--up", type=click.Choice(["y", "z"]), default=None,
              help="trc only: the file's up axis [default: y, as OpenSim reads TRC; z keeps the studio's Z-up world]")
@click.option("--force", is_flag=True, help="overwrite files already in --out")
@workers_option
@threads_option
def export(catalog_path, overrides, sequences, fmt, stage, out_dir, up, force, workers, threads):
    """Write markers as C3D or TRC, poses as BVH, or a UUO report, one per sequence (computes missing partitions
    first); files already in --out are refused unless --force."""
    for path in export_files(load_catalog(catalog_path, overrides), sequences, fmt, stage, Path(out_dir), workers,
                             processes=not threads, up=up, force=force):
        click.echo(f"wrote {path}")


@main.command()
@catalog_option
@set_option
@sequences_option
@click.option("--out", "out_dir", default="report", show_default=True, type=click.Path(file_okay=False),
              help="folder for report.html and its figures")
@workers_option
@threads_option
def report(catalog_path, overrides, sequences, out_dir, workers, threads):
    """An HTML report of the catalog's run, own takes too: per marker tracked frames, gaps, residuals and views,
    trajectories, an interactive 3D view, and with ground truth the accuracy (computes missing partitions first)."""
    catalog = load_catalog(catalog_path, overrides)
    store = Store(catalog.root)
    plan = build_plan(catalog, sequences)
    compute_missing(plan.items.values(), store, workers=workers, processes=not threads, what="cannot report",
                    report=_stage_lines())
    page, images, _ = build_report(catalog, plan, store, Path(out_dir), title=f"mocapflow report: {catalog_path}")
    for path in images + [page]:
        click.echo(f"wrote {path}")


@main.command()
@click.option("--system", "system", default="deepmocap", show_default=True, type=click.Choice(DEMO_CHOICES),
              help="which system to show (all: the three in turn, each in OUT/<system>/)")
@click.option("--out", "out_dir", default=None, type=click.Path(file_okay=False),
              help="folder for the demo's catalog, cache, exports and report [default: mocapflow-demo, or "
                   "mocapflow-demo-<system> for another system than deepmocap]")
@click.option("--motion", "motions", multiple=True, metavar="EXERCISE",
              help="a studio exercise (repeatable) [deepmocap: jumping_jack, uuo: side_reaches, suit: classic_squat]")
@click.option("--frames", default=None, type=int,
              help="frames per take [deepmocap 45 and uuo 30 at 30 fps, suit 2 at 5 fps]")
@click.option("--plan", "show_plan", is_flag=True,
              help="print what each demo would film and run (stages, partitions, exports) and run nothing")
@workers_option
@threads_option
@click.option("--json", "as_json", is_flag=True,
              help="print the figures as one JSON object, the last line of stdout (with all: one object per system)")
def demo(system, out_dir, motions, frames, show_plan, workers, threads, as_json):
    """Each capture system on a small studio take of the mesh body: accuracy table, its files and an HTML report."""
    out = Path(out_dir or ("mocapflow-demo" if system == "deepmocap" else f"mocapflow-demo-{system}"))
    places = demo_folders(out, system)
    options = {s: DemoOptions(motions=tuple(motions), frames=frames, system=s) for s in places}
    for s in places:  # every system's options checked before anything runs
        options[s] = options[s].resolved()
    if show_plan:
        for s, folder in places.items():
            click.echo(describe_demo(folder, options[s]))
        return
    figures = {}
    for s, folder in places.items():
        if len(places) > 1:
            click.echo(f"== {s}: {folder} ==")
        with contextlib.ExitStack() as logs:  # each system's run in its own log file
            text, summary, written = run_demo(
                folder, options[s], workers=workers, processes=not threads,
                log=lambda store, s=s: logs.enter_context(run_log(store, f"demo --system {s}")), report=_stage_lines())
        click.echo(text)
        for path in written:
            click.echo(f"wrote {path}")
        click.echo(_log_said(summary.pop("log", None), Store(str(folder / "storage"))))
        figures[s] = summary
    if as_json:
        click.echo(json.dumps(figures[system] if system != "all" else figures))


@main.command()
@catalog_option
@set_option
@sequences_option
@workers_option
@threads_option
@click.option("--json", "as_json", is_flag=True, help="print the figures as one JSON object, the last line of stdout")
def evaluate(catalog_path, overrides, sequences, workers, threads, as_json):
    """Accuracy of the catalog's stages on its evaluation split (computes missing partitions first)."""
    catalog = load_catalog(catalog_path, overrides)
    store = Store(catalog.root)
    plan = evaluation_plan(catalog, sequences)
    compute_missing(plan.items.values(), store, workers=workers, processes=not threads, what="cannot evaluate")
    result = run_evaluation(catalog, plan, store)
    click.echo(table(result))
    if as_json:
        click.echo(json.dumps(headline(result)))


@main.command()
@catalog_option
@set_option
@sequences_option
@workers_option
@threads_option
@click.option("--out", "out_dir", default=None, type=click.Path(file_okay=False),
              help="also write the comparison page (compare.html and its figures) in this folder")
@click.option("--json", "as_json", is_flag=True, help="print the figures as one JSON object, the last line of stdout")
def compare(catalog_path, overrides, sequences, workers, threads, out_dir, as_json):
    """Every system that filmed the catalog's joint take, scored on the same truth frames: MPJPE per frame and per
    body part, surface error, completeness, compute seconds per captured second, what each needs (computes missing
    partitions first)."""
    catalog = load_catalog(catalog_path, overrides)
    store = Store(catalog.root)
    plan = build_plan(catalog, sequences)
    compute_missing(plan.items.values(), store, workers=workers, processes=not threads, what="cannot compare",
                    report=_stage_lines())
    result = compare_plan(catalog, plan, store)
    click.echo(compare_table(result))
    if out_dir is not None:
        for path in write_compare_page(Path(out_dir), result, title=f"mocapflow compare: {catalog_path}"):
            click.echo(f"wrote {path}")
    if as_json:
        click.echo(json.dumps(compare_headline(result)))


def _matrix(plan: Plan, stages: list[str], cells: dict[str, str]) -> str:
    """Rows: stages; columns: sequence/view, or the sequence where it has no views (marker files). A per-sequence
    stage fills every view column of its sequence, a per-dataset stage every column of its dataset."""
    columns = [(s.id, v) for s in plan.sequences for v in (s.views or [None])]
    header = ["stage"] + [s if v is None else f"{s}/{v}" for s, v in columns]
    rows = [header]
    for stage in stages:
        row = [stage]
        for seq, view in columns:
            row.append(cells.get(f"{stage}/{seq}/{view}") or cells.get(f"{stage}/{seq}")
                       or cells.get(f"{stage}/{plan.dataset_of.get(seq)}") or "")
        rows.append(row)
    widths = [max(len(r[c]) for r in rows) for c in range(len(header))]
    return "\n".join("  ".join(cell.ljust(w) for cell, w in zip(r, widths)).rstrip() for r in rows)


if __name__ == "__main__":  # pragma: no cover
    main()

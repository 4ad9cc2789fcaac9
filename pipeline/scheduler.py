"""Scheduling partitions with Dask.

A stage that works region by region runs as *units* (execute.py): one Dask task per frame region of
a group of partitions, the stages of one sequence x view (masks -> flow -> heatmaps -> reflectors2d)
or of one sequence, each unit after the group's previous region. Other partitions (whole-sequence
filters, training, the source stage) run as one task each. A unit waits for the units of other
groups that write the frames it reads. Tasks are handed to Dask as they become ready, one per free
worker thread, earlier frames first, so the views' groups interleave on the workers region by region,
downstream regions start while upstream ones run, and inputs pass between the members of a unit in
memory. Only small work items and reports travel (never arrays or models): workers read inputs from
storage and write outputs there. Locally a cluster of ``workers`` one-thread worker processes runs them
(or, with ``processes=False``, threads of this process: these start faster, but the Python-heavy
stages then wait on each other's GIL); ``address`` attaches to an existing dask.distributed scheduler
instead (``dask scheduler`` + ``dask worker``), whose lost workers' tasks are rescheduled on the others.
"""

from __future__ import annotations

import heapq
import importlib
import logging
import os
import sys
import threading
import time
import uuid
from collections import Counter
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Callable, Iterator

import dask
from tqdm import tqdm

from mocapflow.pipeline import registry
from mocapflow.pipeline.errors import PlanError
from mocapflow.pipeline.execute import Result, Unit, run_partition, run_unit, spans
from mocapflow.pipeline.locks import RunContext, working_for
from mocapflow.pipeline.plan import WorkItem, held_versions

log = logging.getLogger(__name__)


THREAD_VARIABLES = ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS", "OPENCV_FOR_THREADS_NUM")


@contextmanager
def dask_client(workers: int, address: str | None, *, processes: bool = True) -> Iterator:
    """A client of the scheduler at ``address``, or of a local cluster of ``workers`` one-thread worker processes
    (``processes``) or worker threads of this process."""
    from distributed import Client, LocalCluster

    quiet = logging.getLogger().getEffectiveLevel() > logging.DEBUG
    for name in ("distributed", "distributed.scheduler", "distributed.worker", "distributed.core",
                 "distributed.http.proxy", "distributed.nanny"):
        logging.getLogger(name).setLevel(logging.ERROR if quiet else logging.DEBUG)
    if address:
        check_address(address)
        try:
            client = Client(address, timeout="15s")
        except (OSError, TimeoutError) as exc:
            raise PlanError(f"cannot reach the Dask scheduler at {address!r} ({exc}); start one with "
                            "`dask scheduler` and pass the address it prints") from exc
        with client:
            yield client
        return
    # A worker's statistical profiler (a stack sample of every thread each 10 ms) and memory monitor (every 100 ms)
    # take the GIL from the task threads; nothing here reads their figures, and tasks hand their data over through
    # storage, so there is nothing to spill.
    config = {"distributed.worker.profile.enabled": False}
    if processes:
        # Each worker process gets its share of the cores for its OpenMP, BLAS and OpenCV thread pools (Dask's
        # default, one, would leave cores idle with fewer workers than cores; the libraries' default, every core,
        # runs 4 threads on 2 cores with 2 workers: 41 s instead of 27 s for the benchmark take). Dask's
        # MALLOC_TRIM_THRESHOLD_ is left out: it hands each freed frame array back to the system, and the tasks
        # took half as long again. Non-daemonic, so that a task may start processes (training's data loaders).
        limits = thread_limits(workers)
        config.update({"distributed.worker.daemon": False, "distributed.nanny.pre-spawn-environ": limits,
                       "distributed.worker.multiprocessing-method": _start_method(limits)})
        if config["distributed.worker.multiprocessing-method"] == "forkserver":
            _preload_forkserver()
    n_workers, threads = (max(1, workers), 1) if processes else (1, max(1, workers))
    # No dashboard; the scheduler still serves its HTTP routes, by default on port 8787 with a warning where that
    # port is taken: a free local port instead.
    no_dashboard = {"dashboard": False, "dashboard_address": "127.0.0.1:0"}
    with dask.config.set(config), \
            LocalCluster(n_workers=n_workers, threads_per_worker=threads, processes=processes, memory_limit=0,
                         dashboard_address=None, scheduler_kwargs=no_dashboard, silence_logs=logging.ERROR) as cluster, \
            Client(cluster) as client:
        yield client


# What a worker process imports before its first task: distributed, the engine's worker side, the built-in systems
# (their task declarations; no torch, no thread pools started). A forkserver imports them once per run and forks
# each worker from it, where spawned workers would each import them anew (about 1.5 s of CPU each).
WORKER_PRELOAD = ("distributed", "mocapflow.pipeline.scheduler", "mocapflow.systems.deepmocap", "mocapflow.systems.uuo",
                  "mocapflow.systems.suit", "mocapflow.systems.studio")
_forkserver_limits: dict[str, str] | None = None  # the thread limits the forkserver of this process started with


def _start_method(limits: dict[str, str]) -> str:
    """How local worker processes start: forked from this process's forkserver, whose preloaded libraries read
    their thread pool sizes when it started (the first cluster of this process), so only while ``limits`` are
    those; spawned otherwise (a later cluster of another size in the same process)."""
    global _forkserver_limits
    if _forkserver_limits is None:
        _forkserver_limits = dict(limits)
    return "forkserver" if limits == _forkserver_limits else "spawn"


def _preload_forkserver() -> None:
    """Set the forkserver's preload to WORKER_PRELOAD (a forkserver already running keeps what it has)."""
    import multiprocessing

    from distributed.utils import get_mp_context

    with dask.config.set({"distributed.worker.multiprocessing-method": "forkserver"}):
        get_mp_context()  # distributed sets its own preload on its first call: ours comes after and replaces it
    multiprocessing.get_context("forkserver").set_forkserver_preload(list(WORKER_PRELOAD))


def thread_limits(workers: int) -> dict[str, str]:
    """The thread pool sizes of a worker process, one of ``workers`` on this machine: its share of the cores,
    unless this process's environment sets them."""
    share = str(max(1, (os.cpu_count() or 1) // max(1, workers)))
    return {name: os.environ.get(name, share) for name in THREAD_VARIABLES}


def _warm_imports(items: list[WorkItem]) -> None:
    """Import, in a background thread, what the planned tasks import on their first call: the modules of lazily
    registered tasks, and torch where a task takes weights. The first region to need torch would otherwise import
    it (about 1.5 s) while the other worker threads wait on the import lock; this way it loads while the cluster
    starts and the first regions' other stages run."""
    modules = {item.spec.fn.module for item in items if isinstance(item.spec.fn, registry.Lazy)}
    if any(item.weights for item in items):
        modules.add("torch")
    modules = sorted(modules)

    def load() -> None:
        for name in modules:
            try:
                importlib.import_module(name)
            except (ImportError, OSError, RuntimeError) as exc:  # the task's own import reports it
                log.debug("warm-up import of %s failed: %s", name, exc)

    if modules:
        threading.Thread(target=load, name="warm-imports", daemon=True).start()


def run_items(items: list[WorkItem], *, workers: int = 2, address: str | None = None, processes: bool = True,
              keep_going: bool = False, progress: bool = True, units: bool = True,
              report: Callable[[str], None] | None = None, run_id: str | None = None) -> list[Result]:
    """Run ``items`` (topologically ordered) and return one Result per item, in order. ``processes``: local
    workers are processes (else threads of this process); ``units``: run the stages that work region by region
    as units (the default); False: every partition as one task. Each stage whose partitions have all finished
    is logged (INFO) as one line, also handed to ``report`` (the CLI prints it where there is no progress bar);
    each task, its worker and its partitions are logged too. ``run_id``: the run's id (its run lease's), which its
    workers' locks carry: a retry of a task whose worker died takes that worker's locks over at once."""
    if not items:
        return []
    if not address and not processes:  # worker processes, local or remote, import for themselves
        _warm_imports(items)
    graph = _graph(plan_tasks(items, units=units))
    tasks_of = Counter(pid for task in graph for pid in task.ids)
    stages = _StageLines(items, tasks_of, report)
    reports: dict[str, list[Result]] = {}
    bar = tqdm(total=len(items), unit="part", file=sys.stderr, disable=not progress, dynamic_ncols=True)
    try:
        with dask_client(workers, address, processes=processes) as client:
            log.info("running %d partition(s) of %d stage(s) as %d task(s) on %s", len(items), len(stages.left),
                     len(graph), address or f"{workers} local worker {'processes' if processes else 'threads'}")
            for task, results in _dispatch(client, graph, run_id or uuid.uuid4().hex[:12]):
                for r in results:
                    reports.setdefault(r.partition, []).append(r)
                if task.finishes:
                    bar.set_postfix_str(task.ids[-1], refresh=False)
                    bar.update(len(task.ids))
                    stages.finished(task.ids, reports)
                if not keep_going and any(r.status == "failed" for r in results):
                    break
    finally:
        bar.close()
    results = [_summary(i.partition.id, reports.get(i.partition.id, []), tasks_of[i.partition.id]) for i in items]
    for message in dict.fromkeys(w for r in results for w in r.warnings):  # a reader's or a task's, said once
        log.warning(message)
    return results


class _StageLines:
    """One line per stage as the last of its partitions finishes: how many executed, were cached or failed, the
    seconds its partitions took (summed over the workers) and when it finished, counted from the run's start."""

    def __init__(self, items: list[WorkItem], tasks_of: Counter, report: Callable[[str], None] | None):
        self.left = Counter(i.partition.stage for i in items)
        self.total = dict(self.left)
        self.counts: dict[str, Counter] = {stage: Counter() for stage in self.left}
        self.stage_of = {i.partition.id: i.partition.stage for i in items}
        self.tasks_of = tasks_of
        self.report = report
        self.seconds: Counter = Counter()  # stage -> its partitions' own seconds, summed over workers
        self.started = time.perf_counter()

    def finished(self, pids: list[str], reports: dict[str, list[Result]]) -> None:
        for pid in pids:
            stage = self.stage_of[pid]
            result = _summary(pid, reports.get(pid, []), self.tasks_of[pid])
            self.counts[stage][result.status] += 1
            self.seconds[stage] += result.seconds
            self.left[stage] -= 1
            if self.left[stage] == 0:
                counts = self.counts[stage]
                line = (f"{stage}: {self.total[stage]} partition(s) done, {counts['executed']} executed, "
                        f"{counts['cached']} cached, {counts['failed']} failed ({self.seconds[stage]:.1f} s of "
                        f"work, finished {time.perf_counter() - self.started:.1f} s into the run)")
                log.info("%s", line)
                if self.report is not None:
                    self.report(line)


@dataclass
class _Task:
    work: WorkItem | Unit
    after: list[int]  # the tasks (indices) whose partitions' frames it reads, or whose region precedes it
    order: tuple[int, int]  # dispatch order among ready tasks: earlier frames first, then plan order
    ids: list[str]  # the partitions it reports on
    finishes: bool  # whether it is the last task of its partitions
    dependents: list[int] = field(default_factory=list)


def _graph(tasks: list[WorkItem | Unit]) -> list[_Task]:
    """Each task with the tasks it runs after."""
    graph: list[_Task] = []
    last: dict[str, int] = {}  # partition -> its latest task
    by_region: dict[str, list[tuple[int, int]]] = {}  # partition run as units -> (region stop, its unit)
    for n, task in enumerate(tasks):
        is_unit = isinstance(task, Unit)
        members = list(task.items) if is_unit else [task]
        ids = [m.partition.id for m in members]
        own = set(ids)
        after = set()
        for dep in (d for m in members for d in m.depends_on if d not in own):
            up = _unit_covering(by_region.get(dep, []), task.stop) if is_unit else None
            up = last.get(dep) if up is None else up
            if up is not None:
                after.add(up)
        if is_unit and not task.first:
            after.add(last[ids[0]])  # the group's previous region
        graph.append(_Task(task, sorted(after), (task.start if is_unit else 0, n), ids, not is_unit or task.last))
        for up in after:
            graph[up].dependents.append(n)
        for pid in ids:
            last[pid] = n
            if is_unit:
                by_region.setdefault(pid, []).append((task.stop, n))
    return graph


def _dispatch(client, graph: list[_Task], run_id: str) -> Iterator[tuple[_Task, list[Result]]]:
    """Run ``graph`` on ``client``'s workers, yielding each task with its Results as it finishes.

    The tasks are handed to Dask one per free worker thread, the ready task with the earliest frames first, its
    upstream tasks' Results passed as plain values: each task goes to the worker that is free, where Dask would
    otherwise queue it behind the worker that ran its upstream task (a view's chain of regions sticking to one
    worker and finishing alone at the end)."""
    from distributed import as_completed

    waiting = [len(t.after) for t in graph]
    ready = [(t.order, n) for n, t in enumerate(graph) if not t.after]
    heapq.heapify(ready)
    done: dict[int, list[Result]] = {}
    running: dict = {}  # future -> its task
    finished = as_completed()
    try:
        while ready or running:
            slots = max(1, sum(client.nthreads().values()))  # the workers' threads, as they come and go
            while ready and len(running) < slots:
                n = heapq.heappop(ready)[1]
                task = graph[n]
                upstream = [done[u] for u in task.after]
                if isinstance(task.work, Unit):
                    fut = client.submit(_on_worker, run_id, run_unit, task.work, *upstream,
                                        key=f"{task.work.id}-{run_id}", pure=False)
                else:
                    fut = client.submit(_on_worker, run_id, run_partition, task.work, *upstream,
                                        key=f"{task.work.partition.id}-{task.work.key}-{run_id}", pure=False)
                log.debug("submitted %s", _task_name(task))
                running[fut] = n
                finished.add(fut)
            fut = next(finished)
            n = running.pop(fut)
            done[n] = _results(fut, graph[n].ids, _task_name(graph[n]))
            for d in graph[n].dependents:
                waiting[d] -= 1
                if not waiting[d]:
                    heapq.heappush(ready, (graph[d].order, d))
            yield graph[n], done[n]
    finally:
        if running:
            client.cancel(list(running))


def _unit_covering(units: list[tuple[int, int]], stop: int) -> int | None:
    """The unit (of a partition run region by region, in order) after which frames before ``stop`` are written:
    a unit reads no frame at or after its own stop, and each unit runs after the previous one."""
    return next((n for end, n in units if end >= stop), None)


def plan_tasks(items: list[WorkItem], *, units: bool = True) -> list[WorkItem | Unit]:
    """The tasks that run ``items``: the units of each group (``region_groups``) and the other items as they
    are, each after every task it reads (otherwise in the order of ``items``)."""
    groups = region_groups(items) if units else []
    node_of = {m.partition.id: ("group", g) for g, members in enumerate(groups) for m in members}
    node_of.update({i.partition.id: ("item", n) for n, i in enumerate(items) if i.partition.id not in node_of})
    nodes = list(dict.fromkeys(node_of[i.partition.id] for i in items))
    members = {node: [i for i in items if node_of[i.partition.id] == node] for node in nodes}
    needs = {node: {node_of[d] for m in members[node] for d in m.depends_on if d in node_of} - {node} for node in nodes}
    order, placed = [], set()
    while len(placed) < len(nodes):
        node = next(n for n in nodes if n not in placed and needs[n] <= placed)  # items are topological: one exists
        placed.add(node)
        order.extend(_units(groups[node[1]]) if node[0] == "group" else members[node])
    return order


def _units(members: list[WorkItem]) -> list[Unit]:
    regions = spans(members[0])
    return [Unit(tuple(members), a, b, first=k == 0, last=k == len(regions) - 1) for k, (a, b) in enumerate(regions)]


def region_groups(items: list[WorkItem]) -> list[list[WorkItem]]:
    """The items that work region by region (no look-ahead halo), grouped per sequence x view (per sequence for
    per-sequence stages); in each group the items on its first item's regions, unless an item outside the
    group both reads one of them and is read by one (it would have to run between them)."""
    groups: dict[tuple, list[WorkItem]] = {}
    for item in items:
        spec = item.spec
        if spec.partition in ("view", "sequence") and not spec.source and not spec.whole_sequence \
                and spec.halo[1] == 0:
            groups.setdefault((item.partition.sequence, item.partition.view), []).append(item)
    ids = {i.partition.id: i for i in items}
    out = []
    for members in groups.values():
        members = [m for m in members if spans(m) == spans(members[0])]
        inside = {m.partition.id for m in members}
        outside = {d for m in members for d in m.depends_on if d not in inside and d in ids}
        if not any(_reads_any(ids[d], inside, ids) for d in outside):
            out.append(members)
    return out


def _reads_any(item: WorkItem, targets: set[str], ids: dict, seen: set | None = None) -> bool:
    """Whether ``item`` reads (directly or through other items of the run) one of ``targets``."""
    seen = set() if seen is None else seen
    for dep in item.depends_on:
        if dep in targets:
            return True
        if dep in ids and dep not in seen:
            seen.add(dep)
            if _reads_any(ids[dep], targets, ids, seen):
                return True
    return False


def _on_worker(run_id: str, fn, *args):
    """Run ``fn(*args)`` for run ``run_id`` on a Dask worker, its locks carrying the run and the worker (a retry of
    this task after the worker died takes them over: locks.working_for); returns (the worker's name and address,
    what ``fn`` returned)."""
    from distributed import get_worker

    worker = get_worker()
    with working_for(RunContext(run_id, worker.address, _live_workers)):
        out = fn(*args)
    return f"{worker.name} ({worker.address})", out


def _live_workers() -> set[str]:
    """The addresses of the workers the scheduler holds now (asked from a task)."""
    from distributed import get_client

    return set(get_client().run_on_scheduler(_scheduler_workers))


def _scheduler_workers(dask_scheduler=None) -> list[str]:
    return list(dask_scheduler.workers)


def _task_name(task: _Task) -> str:
    return task.work.id if isinstance(task.work, Unit) else task.work.partition.id


def _results(fut, partitions: list[str], name: str) -> list[Result]:
    try:
        worker, out = fut.result()
    except Exception as exc:  # a lost worker (KilledWorker), cancellation or unpickling failure
        log.info("%s failed: %s: %s", name, type(exc).__name__, exc)
        return [Result(pid, "failed", error=f"{type(exc).__name__}: {exc}") for pid in partitions]
    results = list(out) if isinstance(out, (list, tuple)) else [out]
    log.info("%s ran on worker %s: %s", name, worker,
             ", ".join(f"{r.partition} {r.status}" + (f" {r.seconds:.2f} s" if r.seconds else "") for r in results))
    return results


def _summary(pid: str, reports: list[Result], tasks: int) -> Result:
    """One partition's Result from the reports of its ``tasks`` tasks (a partition run as units: one per region)."""
    if len(reports) < tasks and not any(r.status in ("failed", "skipped") for r in reports):
        return Result(pid, "skipped", error="run stopped after a failure")
    if len(reports) == 1:
        return reports[0]
    for status in ("failed", "skipped"):
        if any(r.status == status for r in reports):
            return next(r for r in reports if r.status == status)
    executed = any(r.status == "executed" for r in reports)
    return Result(pid, "executed" if executed else "cached", seconds=sum(r.seconds for r in reports),
                  regions=sum(r.regions for r in reports),
                  warnings=tuple(dict.fromkeys(w for r in reports for w in r.warnings)))


def compute_missing(items, store, *, workers: int, what: str, processes: bool = True,
                    report: Callable[[str], None] | None = None) -> list[WorkItem]:
    """Run the ``items`` not yet complete in ``store`` and return them; raise PlanError naming the first
    failures (``what``: the purpose, e.g. "cannot export"). ``report``: see run_items. A store this process cannot
    write is read as it is: nothing to compute and no lease (gc cannot delete there either), else a StorageError."""
    if not store.writable():
        todo = [i for i in items if not store.is_complete(i.partition.stage, i.key)]
        if todo:
            raise store.refuse_writes(f"{len(todo)} partition(s) are missing ({what}), e.g. {todo[0].partition.id}")
        return []
    with store.run_lease(f"inputs ({what})", held_versions(items)) as run_id:  # gc deletes none of them
        todo = [i for i in items if not store.is_complete(i.partition.stage, i.key)]
        results = run_items(todo, workers=workers, processes=processes, progress=sys.stderr.isatty(), report=report,
                            run_id=run_id)
    if any(not r.ok for r in results):
        raise PlanError(f"{what}:\n" + "\n".join(failure_report(results)))
    return todo


def check_address(address: str) -> None:
    """Refuse an ``address`` that is no Dask scheduler address (before a run writes anything)."""
    from distributed.comm.addressing import parse_address, parse_host_port  # distributed: only when it is used

    try:
        parse_host_port(parse_address(address)[1])
    except ValueError as exc:
        raise PlanError(f"--scheduler {address!r} is not a Dask scheduler address ({exc}); pass the address "
                        "`dask scheduler` prints, e.g. tcp://10.0.0.5:8786") from exc


ROOT_FAILURES_SHOWN = 20  # partitions that failed on their own, listed with their error before a count of the rest
SKIPPED_SHOWN = 3  # partitions skipped because of them, listed before a count of the rest


def failure_report(results: list[Result]) -> list[str]:
    """What went wrong, root cause first: every partition that failed on its own with its error (up to
    ROOT_FAILURES_SHOWN, then how many more), then the partitions skipped because an upstream one failed or the
    run stopped (a few with their reason, then how many more)."""
    failed = [r for r in results if r.status == "failed"]
    skipped = [r for r in results if r.status == "skipped"]
    def more(n: int, what: str) -> str:
        return f"... and {n} more {what} partition{'s' if n > 1 else ''}"

    lines = [f"FAILED {r.partition}: {r.error}" for r in failed[:ROOT_FAILURES_SHOWN]]
    if len(failed) > ROOT_FAILURES_SHOWN:
        lines.append(more(len(failed) - ROOT_FAILURES_SHOWN, "failed") + " (each in the log)")
    lines += [f"SKIPPED {r.partition}: {r.error}" for r in skipped[:SKIPPED_SHOWN]]
    if len(skipped) > SKIPPED_SHOWN:
        lines.append(more(len(skipped) - SKIPPED_SHOWN, "skipped") + f", {len(skipped)} in all, none of them failed "
                     "on its own")
    return lines

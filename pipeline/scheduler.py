"""Scheduling partitions with Dask.

One Dask task per partition; edges are the partitions it reads. Only small work items travel in
the graph (never arrays or models): workers read inputs from storage and write outputs there.
Locally an in-process cluster with ``workers`` threads runs the graph; ``address`` attaches to an
existing dask.distributed scheduler instead (``dask scheduler`` + ``dask worker``), whose lost
workers' tasks are rescheduled on the others.
"""

from __future__ import annotations

import logging
import sys
import uuid
from contextlib import contextmanager
from typing import Iterator

from tqdm import tqdm

from mocapflow.pipeline.errors import PlanError
from mocapflow.pipeline.execute import Result, run_partition
from mocapflow.pipeline.plan import WorkItem

log = logging.getLogger(__name__)


@contextmanager
def dask_client(workers: int, address: str | None) -> Iterator:
    from distributed import Client, LocalCluster

    quiet = logging.getLogger().getEffectiveLevel() > logging.DEBUG
    for name in ("distributed", "distributed.scheduler", "distributed.worker", "distributed.core",
                 "distributed.http.proxy", "distributed.nanny"):
        logging.getLogger(name).setLevel(logging.ERROR if quiet else logging.DEBUG)
    if address:
        try:
            client = Client(address, timeout="15s")
        except (OSError, TimeoutError) as exc:
            raise PlanError(f"cannot reach the Dask scheduler at {address!r} ({exc}); start one with "
                            "`dask scheduler` and pass the address it prints") from exc
        with client:
            yield client
        return
    with LocalCluster(n_workers=1, threads_per_worker=max(1, workers), processes=False,
                      dashboard_address=None, silence_logs=logging.ERROR) as cluster, Client(cluster) as client:
        yield client


def run_items(items: list[WorkItem], *, workers: int = 2, address: str | None = None,
              keep_going: bool = False, progress: bool = True) -> list[Result]:
    """Run ``items`` (topologically ordered) and return one Result per item, in order."""
    if not items:
        return []
    from distributed import as_completed

    run_id = uuid.uuid4().hex[:8]
    with dask_client(workers, address) as client:
        futures, owner = {}, {}
        for item in items:
            ups = [futures[d] for d in item.depends_on if d in futures]
            fut = client.submit(run_partition, item, *ups, key=f"{item.partition.id}-{item.key}-{run_id}", pure=False)
            futures[item.partition.id] = fut
            owner[fut.key] = item.partition.id
        results: dict[str, Result] = {}
        bar = tqdm(total=len(futures), unit="part", file=sys.stderr, disable=not progress, dynamic_ncols=True)
        try:
            for fut in as_completed(list(futures.values())):
                pid = owner[fut.key]
                results[pid] = _result(fut, pid)
                bar.set_postfix_str(pid, refresh=False)
                bar.update()
                if results[pid].status == "failed" and not keep_going:
                    client.cancel([f for f in futures.values() if not f.done()])
                    break
        finally:
            bar.close()
    return [results.get(i.partition.id) or Result(i.partition.id, "skipped", error="run stopped after a failure")
            for i in items]


def _result(fut, pid: str) -> Result:
    try:
        return fut.result()
    except Exception as exc:  # a lost worker (KilledWorker), cancellation or unpickling failure
        return Result(pid, "failed", error=f"{type(exc).__name__}: {exc}")


def compute_missing(items, store, *, workers: int, what: str) -> list[WorkItem]:
    """Run the ``items`` not yet complete in ``store`` and return them; raise PlanError naming the first
    failures (``what``: the purpose, e.g. "cannot export")."""
    todo = [i for i in items if not store.is_complete(i.partition.stage, i.key)]
    failed = [r for r in run_items(todo, workers=workers, progress=sys.stderr.isatty()) if not r.ok]
    if failed:
        raise PlanError(f"{what}: " + "; ".join(f"{r.partition}: {r.error}" for r in failed[:5]))
    return todo

"""Units: the stages that work region by region run frame region by frame region, per sequence x view (or per
sequence), members passing their outputs on in memory; the artifacts equal a partition-by-partition run."""

from __future__ import annotations

import json

import numpy as np

from conftest import PLUGINS, assert_same_artifacts, last_json, mocapflow, read_artifacts
from mocapflow.pipeline import execute, registry, scheduler
from mocapflow.pipeline.catalog import load_catalog
from mocapflow.pipeline.execute import Unit, run_unit
from mocapflow.pipeline.plan import build_plan
from mocapflow.pipeline.scheduler import plan_tasks, region_groups, run_items
from mocapflow.pipeline.storage import Store

FLAKY_CATALOG = """\
plugins: [toytasks]
storage: {{root: storage/, region_frames: 4}}
datasets:
  rec: {{kind: zarr, path: data}}
stages:
  frames: {{task: ingest}}
  scaled: {{task: scale, inputs: [frames], params: {{factor: 3}}}}
  flaked: {{task: flaky, inputs: [scaled], params: {{bad_view: cam1}}}}
  diffed: {{task: diff, inputs: [flaked]}}
"""


def toy_plan(project, monkeypatch):
    monkeypatch.syspath_prepend(str(PLUGINS))
    catalog = load_catalog(project / "catalog.yaml")
    registry.import_plugins(catalog.plugins)
    return catalog, build_plan(catalog)


def test_groups_hold_a_views_stages_and_every_unit_follows_what_it_reads(toy_project, monkeypatch):
    _, plan = toy_plan(toy_project(), monkeypatch)  # 2 sequences x 2 views, 20 frames, regions of 4
    items = list(plan.items.values())
    groups = {tuple(m.partition.id for m in g) for g in region_groups(items)}
    assert groups == {("scaled/seqA/cam0", "diffed/seqA/cam0"), ("scaled/seqA/cam1", "diffed/seqA/cam1"),
                      ("scaled/seqB/cam0", "diffed/seqB/cam0"), ("scaled/seqB/cam1", "diffed/seqB/cam1"),
                      ("summed/seqA",), ("summed/seqB",)}  # the source stage `frames` runs as one task
    tasks = plan_tasks(items)
    units = [t for t in tasks if isinstance(t, Unit)]
    assert len(units) == 6 * 5 and len(tasks) == 6 * 5 + 2
    cam0 = [(u.start, u.stop, u.first, u.last) for u in units if u.items[0].partition.id == "scaled/seqA/cam0"]
    assert cam0 == [(0, 4, True, False), (4, 8, False, False), (8, 12, False, False), (12, 16, False, False),
                    (16, 20, False, True)]
    written: dict[str, int] = {}  # partition -> frames written by the tasks so far
    for task in tasks:
        members = task.items if isinstance(task, Unit) else (task,)
        stop = task.stop if isinstance(task, Unit) else task.sequence.n_frames
        for m in members:
            assert all(written.get(d, 0) >= stop for d in m.depends_on), (m.partition.id, task)
            assert written.get(m.partition.id, 0) == (task.start if isinstance(task, Unit) else 0)
            written[m.partition.id] = stop
    assert plan_tasks(items, units=False) == items


def test_units_write_what_partitions_write_with_the_right_values(toy_project, tmp_path_factory, monkeypatch):
    project = toy_project()
    projects = {True: project, False: _copy_inputs(project, tmp_path_factory.mktemp("partitions"))}
    for units, project in projects.items():
        _, plan = toy_plan(project, monkeypatch)
        results = run_items(list(plan.items.values()), workers=2, units=units, progress=False)
        assert all(r.status == "executed" for r in results), [r for r in results if not r.ok]
        assert {r.partition: r.regions for r in results}["diffed/seqA/cam1"] == 5
    by_units, by_partitions = (read_artifacts(projects[m] / "storage") for m in (True, False))
    assert_same_artifacts(by_units, by_partitions)
    values = {pid: a for (pid, _), a in by_units.items()}
    depth = values["frames/seqB"]["depth"].astype(np.float32)  # (view, frame, y, x)
    np.testing.assert_array_equal(values["scaled/seqB/cam1"]["value"][0], depth[1] * 3)
    np.testing.assert_array_equal(values["diffed/seqB/cam1"]["value"][0, 1:], np.diff(depth[1] * 3, axis=0))
    np.testing.assert_array_equal(values["diffed/seqB/cam1"]["value"][0, 0], depth[1, 0] * 3)
    np.testing.assert_array_equal(values["summed/seqB"]["total"], depth.sum(axis=0) * 3)
    lineage = json.loads(next((projects[True] / "storage" / "diffed").glob("*/lineage.json")).read_text())
    assert lineage["compute_seconds"] > 0 and lineage["finished"] >= lineage["started"]


def test_halo_frames_come_from_storage_when_the_previous_region_ran_elsewhere(toy_project, tmp_path_factory,
                                                                              monkeypatch):
    project = toy_project()
    reference = _copy_inputs(project, tmp_path_factory.mktemp("reference"))
    mocapflow("run", "--json", cwd=reference)
    _, plan = toy_plan(project, monkeypatch)
    items = list(plan.items.values())
    results = []
    for task in plan_tasks(items):  # one after the other, as if each region ran in a fresh worker process
        execute._TAILS.clear()
        results += run_unit(task) if isinstance(task, Unit) else [execute.run_partition(task)]
    assert all(r.ok for r in results), [r for r in results if not r.ok]
    assert_same_artifacts(read_artifacts(project / "storage"), read_artifacts(reference / "storage"))


def test_a_member_failing_part_way_stops_only_itself_and_what_reads_it(toy_project, tmp_path_factory,
                                                                      monkeypatch):
    project = toy_project()
    (project / "catalog.yaml").write_text(FLAKY_CATALOG.format())
    reference = _copy_inputs(project, tmp_path_factory.mktemp("reference"))
    mocapflow("run", "--json", cwd=reference)
    monkeypatch.setenv("TOY_FLAKY_FROM", "8")
    summary = last_json(mocapflow("run", "--json", "--keep-going", cwd=project, check=False))
    assert set(summary["failed"]) == {"flaked/seqA/cam1", "flaked/seqB/cam1"}
    assert set(summary["skipped"]) == {"diffed/seqA/cam1", "diffed/seqB/cam1"}
    assert {"scaled/seqA/cam1", "flaked/seqA/cam0", "diffed/seqB/cam0"} <= set(summary["executed"])
    assert "flaky on cam1 from frame 8" in summary["errors"]["flaked/seqA/cam1"]
    store = Store(str(project / "storage"))
    flaked = {v.partition: v.key for v in store.versions("flaked")}
    assert store.region_done("flaked", flaked["flaked/seqA/cam1"], 4, 8)  # the regions before the failure stay
    assert not store.region_done("flaked", flaked["flaked/seqA/cam1"], 8, 12)

    monkeypatch.delenv("TOY_FLAKY_FROM")
    summary = last_json(mocapflow("run", "--json", cwd=project))
    assert sorted(summary["executed"]) == ["diffed/seqA/cam1", "diffed/seqB/cam1", "flaked/seqA/cam1",
                                           "flaked/seqB/cam1"]
    assert summary["regions"]["flaked/seqA/cam1"] == 3  # resumed where it failed
    assert_same_artifacts(read_artifacts(project / "storage"), read_artifacts(reference / "storage"))


def _copy_inputs(src, dst):
    import shutil

    shutil.copytree(src / "data", dst / "data")
    shutil.copy(src / "catalog.yaml", dst / "catalog.yaml")
    return dst


def test_lazily_registered_task_modules_are_imported_in_the_background(tmp_path, monkeypatch, caplog):
    """The warm-up imports every lazily registered task's module before any task runs; one that fails to import is
    logged and passed over (the modules after it still load), and the task's own import still raises its error."""
    import logging
    import sys
    import threading
    from types import SimpleNamespace

    import pytest

    (tmp_path / "warm_order.py").write_text("TRIED = []\n")
    (tmp_path / "warm_me.py").write_text("import warm_order\nwarm_order.TRIED.append('warm_me')\nLOADED = True\n")
    (tmp_path / "warm_broken.py").write_text("import warm_order\nwarm_order.TRIED.append('warm_broken')\n"
                                             "raise ImportError('a missing dependency')\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    for module in ("warm_order", "warm_me", "warm_broken"):
        monkeypatch.delitem(sys.modules, module, raising=False)
    for name, module in (("warm_task", "warm_me"), ("warm_broken_task", "warm_broken")):
        monkeypatch.setitem(registry._REGISTRY, name, registry.TaskSpec(
            name=name, fn=registry.Lazy(module, "f"), version="1", params=registry.NoParams, output="x",
            partition="view"))
    caplog.set_level(logging.DEBUG, logger=scheduler.__name__)
    items = [SimpleNamespace(spec=registry.get(t), weights={}) for t in ("warm_broken_task", "warm_task")]
    scheduler._warm_imports(items)
    for thread in [t for t in threading.enumerate() if t.name == "warm-imports"]:
        thread.join(timeout=30)
    assert sys.modules["warm_order"].TRIED == ["warm_broken", "warm_me"]  # the broken module first, then past it
    assert sys.modules["warm_me"].LOADED  # imported before any task ran
    warm_logs = [r.getMessage() for r in caplog.records if r.name == scheduler.__name__ and "warm-up" in r.getMessage()]
    assert warm_logs == ["warm-up import of warm_broken failed: a missing dependency"]
    with pytest.raises(ImportError, match="a missing dependency"):  # left for the task's own import to report
        registry._REGISTRY["warm_broken_task"].fn()
    assert sys.modules["warm_order"].TRIED == ["warm_broken", "warm_me", "warm_broken"]  # imported afresh, not a stub


def test_one_worker_runs_the_ready_task_with_the_earliest_frames_first(toy_project, monkeypatch):
    _, plan = toy_plan(toy_project(), monkeypatch)  # 2 sequences x 2 views, 20 frames, regions of 4
    items = list(plan.items.values())
    graph = scheduler._graph(plan_tasks(items))
    with scheduler.dask_client(1, None, processes=False) as client:
        ran = [task.work for task, results in scheduler._dispatch(client, graph, "order")
               if all(r.status == "executed" for r in results)]
    assert len(ran) == len(graph)  # every task, each once, all executed
    units = [(u.start, u.items[0].partition.id) for u in ran if isinstance(u, Unit)]
    assert [start for start, _ in units] == sorted(start for start, _ in units)  # region by region, every group
    assert units[:6] == [(0, "scaled/seqA/cam0"), (0, "scaled/seqA/cam1"), (0, "summed/seqA"),
                         (0, "scaled/seqB/cam0"), (0, "scaled/seqB/cam1"), (0, "summed/seqB")]


def test_local_workers_are_processes_with_their_share_of_the_cores(monkeypatch):
    import os

    monkeypatch.delenv("OMP_NUM_THREADS", raising=False)
    monkeypatch.setenv("OPENBLAS_NUM_THREADS", "3")  # set by the user: kept
    with scheduler.dask_client(2, None) as client:
        pids = client.run(os.getpid)
        env = client.run(lambda: {name: os.environ.get(name) for name in scheduler.THREAD_VARIABLES})
        daemonic = client.run(lambda: __import__("multiprocessing").current_process().daemon)
    assert len(set(pids.values())) == 2 and os.getpid() not in pids.values()
    share = str(max(1, (os.cpu_count() or 1) // 2))
    assert all(e == {"OMP_NUM_THREADS": share, "MKL_NUM_THREADS": share, "OPENBLAS_NUM_THREADS": "3",
                     "OPENCV_FOR_THREADS_NUM": share} for e in env.values()), env
    assert not any(daemonic.values())  # a task may start processes of its own (training's data loaders)


def test_thread_limits_share_the_cores_between_the_workers(monkeypatch):
    for name in scheduler.THREAD_VARIABLES:
        monkeypatch.delenv(name, raising=False)
    monkeypatch.setattr(scheduler.os, "cpu_count", lambda: 8)
    assert set(scheduler.thread_limits(2).values()) == {"4"}
    assert set(scheduler.thread_limits(3).values()) == {"2"}
    assert set(scheduler.thread_limits(16).values()) == {"1"}
    monkeypatch.setenv("MKL_NUM_THREADS", "5")
    assert scheduler.thread_limits(2) == {"OMP_NUM_THREADS": "4", "MKL_NUM_THREADS": "5", "OPENBLAS_NUM_THREADS": "4",
                                          "OPENCV_FOR_THREADS_NUM": "4"}


def test_a_local_cluster_without_dashboard_leaves_port_8787_alone():
    import socket
    import warnings

    holder = socket.socket()
    try:
        holder.bind(("127.0.0.1", 8787))  # as another cluster's dashboard would
        holder.listen()
    except OSError:
        pass  # already taken, which is the case this test is about
    try:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            with scheduler.dask_client(1, None, processes=False) as client:
                assert sum(client.nthreads().values()) == 1
        assert not [w for w in caught if "already in use" in str(w.message)]
    finally:
        holder.close()


def test_the_failure_report_lists_every_root_failure_before_the_skipped_partitions():
    from mocapflow.pipeline.execute import Result

    skipped = [Result(f"frames/seq{i}", "skipped", error="run stopped after a failure") for i in range(6)]
    failed = [Result(f"scaled/seq{i}/cam1", "failed", error=f"RuntimeError: boom {i}") for i in range(25)]
    ok = [Result("scaled/seq0/cam0", "executed")]
    lines = scheduler.failure_report(skipped + ok + failed)  # the skipped first in plan order, as they can be
    assert lines[:20] == [f"FAILED scaled/seq{i}/cam1: RuntimeError: boom {i}" for i in range(20)]
    assert lines[20] == "... and 5 more failed partitions (each in the log)"
    assert lines[21:24] == [f"SKIPPED frames/seq{i}: run stopped after a failure" for i in range(3)]
    assert lines[24:] == ["... and 3 more skipped partitions, 6 in all, none of them failed on its own"]

"""A real `dask scheduler` + 2 `dask worker` processes on loopback: same outputs; a lost worker is survived."""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from conftest import assert_same_artifacts, env_with_plugins, last_json, mocapflow, read_artifacts, wait_for

DASK = [sys.executable, "-m", "distributed.cli.dask_scheduler"]
WORKER = [sys.executable, "-m", "distributed.cli.dask_worker"]


@pytest.fixture
def cluster(tmp_path):
    """Scheduler and two single-thread workers without nannies (a killed worker stays dead)."""
    sched_file = tmp_path / "scheduler.json"
    procs = [subprocess.Popen(DASK + ["--host", "127.0.0.1", "--port", "0", "--no-dashboard",
                                      "--scheduler-file", str(sched_file)],
                              env=env_with_plugins(), stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)]
    try:
        wait_for(lambda: sched_file.exists() and json.loads(sched_file.read_text()).get("address"), 60, "the scheduler file")
        address = json.loads(sched_file.read_text())["address"]
        workers = []
        for i in range(2):
            workers.append(subprocess.Popen(
                WORKER + [address, "--nthreads", "1", "--no-nanny", "--no-dashboard", "--host", "127.0.0.1",
                          "--local-directory", str(tmp_path / f"w{i}"), "--name", f"w{i}"],
                env=env_with_plugins(), stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL))
        procs += workers
        from distributed import Client

        with Client(address, timeout="20s") as client:
            client.wait_for_workers(2, timeout=60)
        yield address, workers
    finally:
        for proc in procs:
            if proc.poll() is None:
                proc.send_signal(signal.SIGKILL)
            proc.wait()


def _local_run(toy_run, **options) -> tuple[Path, dict]:
    """A toy project with nothing computed, and the artifacts of a local run of it (toy_run's, made once)."""
    project, _ = toy_run(**options)
    reference = read_artifacts(project / "storage")
    shutil.rmtree(project / "storage")
    return project, reference


def test_run_on_cluster_equals_local_run(toy_run, cluster):
    address, _ = cluster
    project, reference = _local_run(toy_run)
    summary = last_json(mocapflow("run", "--json", "--scheduler", address, cwd=project))
    assert summary["failed"] == [] and len(summary["executed"]) == 12
    assert_same_artifacts(read_artifacts(project / "storage"), reference)


def test_killing_a_worker_mid_run_still_completes(toy_run, cluster):
    address, workers = cluster
    project, reference = _local_run(toy_run, sleep=0.2, frames=32)
    run = subprocess.Popen([sys.executable, "-m", "mocapflow.cli.commands", "run", "--json", "--scheduler", address],
                           cwd=project, env=env_with_plugins(), stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    wait_for(lambda: len(list((project / "storage").glob("scaled/*/_regions/*"))) >= 3)
    os.kill(workers[0].pid, signal.SIGKILL)
    out, err = run.communicate(timeout=240)
    assert run.returncode == 0, err
    summary = json.loads(out.strip().splitlines()[-1])
    assert summary["failed"] == [] and len(summary["executed"]) == 12
    assert_same_artifacts(read_artifacts(project / "storage"), reference)


def test_unreachable_scheduler_is_a_clear_error(toy_project):
    project = toy_project()
    proc = mocapflow("run", "--scheduler", "tcp://127.0.0.1:1", cwd=project, check=False, timeout=120)
    assert proc.returncode == 2 and "cannot reach the Dask scheduler at 'tcp://127.0.0.1:1'" in proc.stderr

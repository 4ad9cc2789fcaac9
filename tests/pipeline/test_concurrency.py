"""Two runs on one storage root, failures and --keep-going."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
import time

from conftest import assert_same_artifacts, env_with_plugins, last_json, mocapflow, read_artifacts


def test_two_runs_on_one_root_refuse_each_others_partitions_naming_the_holder(toy_project, tmp_path_factory):
    project = toy_project(frames=24, sequences=("seqA",))
    hold = project / "hold"  # the first run's scale tasks wait while this file exists
    hold.write_text("")
    env = {**env_with_plugins(), "TOY_HOLD_WHILE": str(hold)}
    first = subprocess.Popen([sys.executable, "-m", "mocapflow.cli.commands", "run", "--json", "--keep-going"],
                             cwd=project, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.time() + 120
    while not list((project / "storage").glob("scaled/*/.lock")) and time.time() < deadline:
        time.sleep(0.05)
    try:
        second = subprocess.run([sys.executable, "-m", "mocapflow.cli.commands", "run", "--json", "--keep-going"],
                                cwd=project, env=env_with_plugins(), capture_output=True, text=True, timeout=300)
    finally:
        hold.unlink()
    out, _ = first.communicate(timeout=300)
    summaries = {first.pid: json.loads(out.strip().splitlines()[-1]), second: last_json(second)}
    refused = {pid: s["errors"] for pid, s in summaries.items() if s["errors"]}
    assert refused, "the runs overlapped, so at least one partition must have been refused"
    second_summary = summaries[second]
    assert second_summary["errors"], "the later run reaches the earlier run's locked partitions"
    for errors in refused.values():
        for message in errors.values():
            assert "is being written by another run" in message and "wait for it to finish" in message
    assert all(f"pid {first.pid}" in m for m in second_summary["errors"].values())
    # nothing was corrupted: completing the work gives exactly a clean run's result
    assert last_json(mocapflow("run", "--json", cwd=project))["failed"] == []
    reference = tmp_path_factory.mktemp("ref")
    shutil.copytree(project / "data", reference / "data")
    shutil.copy(project / "catalog.yaml", reference / "catalog.yaml")
    mocapflow("run", "--json", cwd=reference)
    assert_same_artifacts(read_artifacts(project / "storage"), read_artifacts(reference / "storage"))


def test_keep_going_continues_past_a_failed_partition_and_lists_it(toy_project):
    project = toy_project()
    (project / "catalog.yaml").write_text((project / "catalog.yaml").read_text().replace(
        "task: scale,", "task: boom,").replace("params: {factor: 3, sleep: 0.0}", "params: {bad_view: cam1}"))
    stop = mocapflow("run", "--json", cwd=project, check=False)
    assert stop.returncode == 1
    assert "FAILED scaled/seq" in stop.stderr and "RuntimeError: boom on cam1" in stop.stderr
    going = mocapflow("run", "--json", "--keep-going", cwd=project, check=False)
    summary = last_json(going)
    assert going.returncode == 1
    assert set(summary["failed"]) == {"scaled/seqA/cam1", "scaled/seqB/cam1"}
    assert {"summed/seqA", "summed/seqB", "diffed/seqA/cam1"} <= set(summary["skipped"])
    assert "diffed/seqA/cam0" in summary["executed"] or "diffed/seqA/cam0" in summary["cached"]

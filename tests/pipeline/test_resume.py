"""kill -9 part-way through a run, then resume: only unfinished regions run, outputs equal a clean run."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time

from conftest import assert_same_artifacts, env_with_plugins, last_json, mocapflow, read_artifacts


def committed_regions(root):
    return sorted(p for p in root.glob("scaled/*/_regions/*"))


def test_kill_dash_nine_then_resume_finishes_only_unfinished_work(toy_project, tmp_path_factory):
    # 2 sequences x 2 views x 10 regions of 4 frames, 0.25 s per region: about 5 s of work on 2 threads.
    project = toy_project(sleep=0.25, frames=40)
    hold = project / "hold"  # created part-way: every region started after it waits, holding its lock
    env = {**env_with_plugins(), "TOY_HOLD_WHILE": str(hold)}
    proc = subprocess.Popen([sys.executable, "-m", "mocapflow.cli.commands", "run", "--json", "--workers", "2"],
                            cwd=project, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            start_new_session=True)
    storage = project / "storage"
    deadline = time.time() + 60
    while len(committed_regions(storage)) < 6 and time.time() < deadline:
        time.sleep(0.05)
    hold.write_text("")
    # kill while both workers sit inside a region under its lock, never in the gap between two regions: two
    # locks held and nothing committed for a second (a region past the hold check when the file appeared commits)
    seen = (-1, 0)
    while time.time() < deadline:
        time.sleep(1.0)
        now = (len(committed_regions(storage)), len(list(storage.glob("scaled/*/.lock"))))
        if now == seen and now[1] == 2:
            break
        seen = now
    # the whole run at once, its worker processes too (as a crash or the OOM killer takes it): a worker left
    # running would finish its region and release its lock, which is a different test
    os.killpg(proc.pid, signal.SIGKILL)
    proc.wait()
    hold.unlink()
    done_before = len(committed_regions(storage))
    assert 6 <= done_before < 40, "the run must be killed part-way through the scaled stage"
    assert len(list(storage.glob("scaled/*/.lock"))) == 2, "the killed run left its locks behind"

    resumed = last_json(mocapflow("run", "--json", cwd=project))
    assert resumed["failed"] == []
    scaled = {p: n for p, n in resumed["regions"].items() if p.startswith("scaled/")}
    assert sum(scaled.values()) == 40 - done_before  # region granularity: nothing committed is redone
    assert set(resumed["executed"]) >= {"diffed/seqA/cam0", "summed/seqB"}

    reference = tmp_path_factory.mktemp("reference")
    ref_project = _copy_inputs(project, reference)
    mocapflow("run", "--json", cwd=ref_project)
    assert_same_artifacts(read_artifacts(project / "storage"), read_artifacts(ref_project / "storage"))
    assert last_json(mocapflow("run", "--json", cwd=project))["executed"] == []


def _copy_inputs(src, dst):
    import shutil

    shutil.copytree(src / "data", dst / "data")
    shutil.copy(src / "catalog.yaml", dst / "catalog.yaml")
    return dst


def test_incomplete_artifact_is_never_read_as_complete(toy_run):
    import pytest

    from mocapflow.pipeline.errors import StorageError
    from mocapflow.pipeline.storage import Store
    from mocapflow.schemas import get_schema

    project, _ = toy_run(until="frames")
    store = Store(str(project / "storage"))
    version = next((project / "storage" / "frames").iterdir())
    (version / "_COMPLETE").unlink()  # as if killed between the last region and the commit
    with pytest.raises(StorageError, match="is not complete"):
        store.open("frames", version.name, get_schema("raw_sequence"))
    rerun = last_json(mocapflow("run", "--json", "--until", "frames", cwd=project))
    assert any(p.startswith("frames/") for p in rerun["executed"])
    assert all(n == 0 for p, n in rerun["regions"].items() if p == f"frames/{version.name}")

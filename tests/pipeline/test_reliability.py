"""Reliability, second round: gc and running runs cooperate, a dead worker of another host is resumed at once,
damaged metadata is found, limits at the door, a full disk, malformed locks."""

from __future__ import annotations

import json
import logging
import os
import re
import signal
import subprocess
import sys
import time
import uuid
from pathlib import Path

import numpy as np
import pytest
import xarray as xr

from conftest import PLUGINS, env_with_plugins, last_json, mocapflow, read_artifacts, wait_for
from mocapflow.pipeline.catalog import COUNT_LIMITS, MAX_EXPANDED_NODES, load_catalog
from mocapflow.pipeline.errors import CatalogError, IntegrityError
from mocapflow.pipeline.locks import HOST_ENV, LEASE_ENV
from mocapflow.pipeline.plan import build_plan
from mocapflow.pipeline.storage import Store

CLI = [sys.executable, "-m", "mocapflow.cli.commands"]


@pytest.fixture(autouse=True)
def _plugins_importable(monkeypatch):
    monkeypatch.syspath_prepend(str(PLUGINS))


def check_scaled_values(project: Path, storage: Path | None = None, factor: float = 3.0) -> int:
    """Every complete `scaled` version (under ``storage``, by default the project's) holds ``factor`` x its raw
    depth; how many there are."""
    artifacts = read_artifacts(storage or project / "storage")
    raw = {p.name.removesuffix(".zarr"): xr.open_zarr(p, consolidated=False, chunks=None)
           for p in (project / "data").glob("*.zarr")}
    n = 0
    for (partition, _), variables in artifacts.items():
        stage, sequence, *view = partition.split("/")
        if stage == "scaled":
            depth = raw[sequence]["depth"].sel(view=view).values.astype(np.float32)
            np.testing.assert_array_equal(variables["value"], depth * np.float32(factor), err_msg=partition)
            n += 1
    return n


# ---- 1. gc and a running run ---------------------------------------------------------------------------------
def unreferencing_catalog(project: Path) -> Path:
    """A catalog over the project's storage root that references no version."""
    other = project / "other.yaml"
    other.write_text("plugins: [toytasks]\nstorage: {root: storage/}\ndatasets:\n  rec: {kind: zarr, path: data}\n"
                     "stages: {}\n")
    return other


def test_gc_keeps_every_version_a_running_run_holds_and_says_why(toy_run):
    project, _ = toy_run(until="frames", sequences=("seqA",))  # complete versions the run will read
    other = unreferencing_catalog(project)
    hold = project / "hold"
    hold.write_text("")
    run = subprocess.Popen(CLI + ["run", "--json"], cwd=project, env={**env_with_plugins(), "TOY_HOLD_WHILE": str(hold)},
                           stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        # both workers hold a scaled version, begun (its lineage written), inside its first region
        wait_for(lambda: len(list((project / "storage").glob("scaled/*/lineage.json"))) == 2, what="two scaled versions")
        versions = sorted(p.parent for p in (project / "storage").glob("*/*/lineage.json"))
        gc = mocapflow("gc", "--catalog", other, cwd=project).stdout
    finally:
        hold.unlink()
    out, err = run.communicate(timeout=300)
    assert run.returncode == 0, err
    kept = [line for line in gc.splitlines() if line.startswith("kept ")]
    # frames (complete, read) and both scaled versions being written
    assert sorted(line.split()[1] for line in kept) == [f"{v.parent.name}/{v.name}" for v in versions], gc
    assert len(versions) == 3
    assert all("in use by run" in line and f"pid {run.pid}" in line for line in kept), gc
    assert f"0 unreferenced version(s) deleted, {len(versions)} kept because a live run holds them" in gc
    assert all(v.is_dir() for v in versions)
    summary = json.loads(out.strip().splitlines()[-1])
    assert summary["failed"] == [] and len(summary["executed"]) == 5
    assert check_scaled_values(project) == 2
    assert list((project / "storage" / "runs").glob("*.json")) == []  # the run's lease ended with it
    # once the run ended, gc deletes them all and says so
    after = mocapflow("gc", "--catalog", other, cwd=project).stdout
    assert "6 unreferenced version(s) deleted, 0 kept" in after
    assert list((project / "storage").glob("*/*/lineage.json")) == []


def test_a_dead_runs_lease_holds_nothing(toy_run):
    project, _ = toy_run(until="frames", sequences=("seqA",))
    [frames] = [p.parent for p in (project / "storage").glob("frames/*/lineage.json")]
    dead = {"host": "otherhost", "pid": 1, "started": 1.0, "run_pid": 1, "run": "run", "token": uuid.uuid4().hex,
            "lease_s": 5.0, "renewed": time.time() - 60, "kind": "run", "run_id": "deadbeef",
            "versions": [["frames", frames.name]]}
    (project / "storage" / "runs").mkdir(exist_ok=True)
    (project / "storage" / "runs" / "deadbeef.json").write_text(json.dumps(dead))
    out = mocapflow("gc", "--catalog", unreferencing_catalog(project), cwd=project, check=False)
    assert out.returncode == 0, out.stderr
    assert f"deleted frames/{frames.name}" in out.stdout and "1 unreferenced version(s) deleted, 0 kept" in out.stdout
    assert not (project / "storage" / "runs" / "deadbeef.json").exists()


def test_a_partition_whose_region_vanished_before_its_commit_fails(toy_project):
    from mocapflow.pipeline.execute import run_unit
    from mocapflow.pipeline.scheduler import plan_tasks

    project = toy_project(sequences=("seqA",), frames=12)
    mocapflow("run", "--json", "--until", "frames", cwd=project)
    catalog = load_catalog(project / "catalog.yaml")
    items = [i for i in build_plan(catalog).items.values() if i.partition.id == "scaled/seqA/cam0"]
    units = plan_tasks(items)
    assert [(u.start, u.stop) for u in units] == [(0, 4), (4, 8), (8, 12)]
    store = Store(catalog.root)
    results = [run_unit(units[0]), run_unit(units[1])]
    (Path(store.version_dir("scaled", items[0].key)) / "_regions" / "00000000-00000004").unlink()  # as a deleter would
    [last] = run_unit(units[2], *results)
    assert last.status == "failed" and not last.ok
    assert "partition scaled/seqA/cam0 was not committed: frames 0-4" in last.error and "run again" in last.error
    assert not store.is_complete("scaled", items[0].key)


# ---- 2. a dead worker of another host --------------------------------------------------------------------------
def test_a_retry_takes_over_the_lock_of_a_dead_worker_of_another_host_at_once(toy_project, tmp_path):
    project = toy_project(sequences=("seqA",))
    hold = project / "hold"
    hold.write_text("")
    env = {**env_with_plugins(), "TOY_HOLD_WHILE": str(hold), LEASE_ENV: "600"}  # without the fence: a 600 s wait
    sched_file = tmp_path / "scheduler.json"
    procs = [subprocess.Popen([sys.executable, "-m", "distributed.cli.dask_scheduler", "--host", "127.0.0.1", "--port",
                               "0", "--no-dashboard", "--scheduler-file", str(sched_file)], env=env,
                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)]
    try:
        wait_for(lambda: json.loads(sched_file.read_text()).get("address"), what="the scheduler")
        address = json.loads(sched_file.read_text())["address"]
        for name, host in (("w0", None), ("n2", "node2")):
            procs.append(subprocess.Popen(
                [sys.executable, "-m", "distributed.cli.dask_worker", address, "--nthreads", "1", "--no-nanny",
                 "--no-dashboard", "--host", "127.0.0.1", "--local-directory", str(tmp_path / name), "--name", name],
                env={**env, HOST_ENV: host} if host else env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL))
        run = subprocess.Popen(CLI + ["run", "--json", "--scheduler", address], cwd=project, env=env,
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)

        def node2_lock():
            return [p for p in (project / "storage").glob("scaled/*/.lock")
                    if json.loads(p.read_text() or "{}").get("host") == "node2"]

        wait_for(node2_lock, what="a scaled lock of the worker on node2")
        os.kill(procs[2].pid, signal.SIGKILL)
        procs[2].wait()
        hold.unlink()
        out, err = run.communicate(timeout=300)
    finally:
        for proc in procs:
            if proc.poll() is None:
                proc.send_signal(signal.SIGKILL)
            proc.wait()
    assert run.returncode == 0, err
    summary = json.loads(out.strip().splitlines()[-1])
    assert summary["failed"] == [] and len(summary["executed"]) == 6
    assert check_scaled_values(project) == 2
    assert list((project / "storage").rglob(".lock*")) == []


# ---- 3. damage outside the chunks ------------------------------------------------------------------------------
def test_damaged_array_metadata_is_found_refused_and_rewritten(toy_project):
    project = toy_project(sequences=("seqA",))
    mocapflow("run", "--json", "--until", "scaled", cwd=project)
    clean = read_artifacts(project / "storage")
    version = next(p.parent for p in (project / "storage").glob("scaled/*/lineage.json")
                   if '"scaled/seqA/cam0"' in p.read_text())
    meta = version / "data.zarr" / "value" / "zarr.json"
    text = meta.read_text()
    assert '"endian": "little"' in text
    meta.write_text(text.replace('"endian": "little"', '"endian": "big"'))

    catalog = load_catalog(project / "catalog.yaml")
    item = build_plan(catalog).item("scaled", "seqA", "cam0")
    with pytest.raises(IntegrityError, match=r"metadata value/zarr\.json has digest .*, recorded"):
        _ = Store(catalog.root).open("scaled", item.key, item.stage.schema)["value"].values

    found = mocapflow("verify", cwd=project, check=False)
    assert found.returncode == 1
    assert f"DAMAGED scaled/seqA/cam0 (scaled/{version.name}): 1 chunk(s), in meta" in found.stdout
    assert "value/zarr.json has digest" in found.stdout and "2 intact, 1 damaged" in found.stdout
    rerun = last_json(mocapflow("run", "--json", "--until", "scaled", cwd=project))
    assert rerun["executed"] == ["scaled/seqA/cam0"] and rerun["regions"] == {"scaled/seqA/cam0": 5}
    assert json.loads(meta.read_text()) == json.loads(text)
    after = read_artifacts(project / "storage")
    assert after.keys() == clean.keys()
    for key in clean:
        for name in clean[key]:
            np.testing.assert_array_equal(after[key][name], clean[key][name], err_msg=f"{key} {name}")
    assert "3 intact, 0 damaged" in mocapflow("verify", cwd=project).stdout


def test_changed_group_attributes_are_found(toy_run):
    project, _ = toy_run(until="frames", sequences=("seqA",))
    [group] = (project / "storage").glob("frames/*/data.zarr/zarr.json")
    attrs = json.loads(group.read_text())
    attrs["attributes"]["fps"] = 1000.0
    group.write_text(json.dumps(attrs))
    found = mocapflow("verify", cwd=project, check=False)
    assert found.returncode == 1 and "zarr.json has digest" in found.stdout and "0 intact, 1 damaged" in found.stdout


# ---- 4. limits at the door -------------------------------------------------------------------------------------
def alias_bomb(levels: int) -> str:
    lines = ['a0: &a0 ["lol", "lol", "lol", "lol", "lol", "lol", "lol", "lol", "lol"]']
    for n in range(1, levels + 1):
        lines.append(f"a{n}: &a{n} [{', '.join([f'*a{n - 1}'] * 9)}]")
    return "\n".join(lines) + "\n"


def test_an_alias_bomb_is_refused_naming_the_file_line_and_limit(tmp_path):
    path = tmp_path / "catalog.yaml"
    path.write_text(alias_bomb(9))
    with pytest.raises(CatalogError) as exc:
        load_catalog(path)
    # level 5 holds 9**5 + ... values: the alias on line 7 (level 6) passes the limit
    assert re.search(rf"catalog\.yaml \(line 6\): alias \*a4 makes the expanded document over {MAX_EXPANDED_NODES}",
                     str(exc.value)), str(exc.value)
    path.write_text(alias_bomb(2) + "plugins: []\n")  # a few aliases are fine
    with pytest.raises(CatalogError, match="unknown key 'a0'"):
        load_catalog(path)


def test_an_oversized_catalog_is_refused(tmp_path):
    path = tmp_path / "catalog.yaml"
    path.write_text("# padding\n" * 200_000)
    with pytest.raises(CatalogError, match=r"catalog\.yaml \(line 200001\): the catalog is 2000000 bytes, over the "
                                           r"limit of 1048576 bytes"):
        load_catalog(path)


STUDIO = """\
storage: {{root: storage/}}
datasets:
  studio:
    kind: studio
    defaults: {{frames: {frames}, views: 3}}
    sequences:
      s1: {{motion: jumping_jack, views: {views}}}
stages:
  frames: {{task: ingest}}
"""


@pytest.mark.parametrize("frames,views,bad", [(100_000_000, 3, "frames"), (60, 1000, "views")])
def test_counts_over_their_limit_are_refused_when_the_catalog_loads(tmp_path, frames, views, bad):
    path = tmp_path / "catalog.yaml"
    path.write_text(STUDIO.format(frames=frames, views=views))
    line = 5 if bad == "frames" else 7
    where = "datasets.studio.defaults.frames" if bad == "frames" else "datasets.studio.sequences.s1.views"
    with pytest.raises(CatalogError) as exc:
        load_catalog(path)
    assert str(exc.value).startswith(f"catalog.yaml (line {line}): {where}: {bad}={frames if bad == 'frames' else views} "
                                     f"is over the limit of {COUNT_LIMITS[bad]}"), str(exc.value)
    proc = mocapflow("run", "--dry-run", cwd=tmp_path, check=False)
    assert proc.returncode == 2 and f"over the limit of {COUNT_LIMITS[bad]}" in proc.stderr


def test_a_partition_over_the_ceiling_is_refused_before_any_worker_starts(toy_project):
    project = toy_project(sequences=("seqA",))
    proc = mocapflow("run", "--json", "--set", "storage.max_partition_bytes=1000", cwd=project, check=False)
    assert proc.returncode == 2 and "(storage.max_partition_bytes)" in proc.stderr
    need = int(re.search(r"--set storage\.max_partition_bytes=(\d+)", proc.stderr).group(1))
    # the biggest partition: a region of 4 frames of both views of the raw stores' 12 x 16 images, as the reader
    # states their size
    assert need == 4 * 2 * 12 * 16 * 4 and "partition frames/seqA (the biggest of 6 over the ceiling)" in proc.stderr
    assert not (project / "storage").exists()
    assert mocapflow("run", "--json", "--set", f"storage.max_partition_bytes={need}", cwd=project).returncode == 0


# ---- 5. a full disk --------------------------------------------------------------------------------------------
@pytest.fixture
def small_disk(tmp_path):
    """A 2 MB tmpfs (root only), unmounted at the end."""
    mount = tmp_path / "small"
    mount.mkdir()
    done = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=2m", "tmpfs", str(mount)], capture_output=True)
    if done.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here: {done.stderr.decode().strip()}")
    try:
        yield mount
    finally:
        subprocess.run(["umount", "-l", str(mount)], check=False)


def test_a_full_disk_leaves_no_claim_and_says_so_in_one_line(toy_project, small_disk):
    project = toy_project(root=str(small_disk / "storage") + "/", sequences=("seqA",), frames=40)
    (small_disk / "filler").write_bytes(b"\0" * 1_700_000)  # room for the frames and part of the rest
    proc = mocapflow("run", "--json", "--keep-going", cwd=project, check=False)
    summary = last_json(proc)
    assert proc.returncode == 1 and summary["failed"], proc.stderr
    assert "Logging error" not in proc.stderr and "Traceback" not in proc.stderr, proc.stderr
    messages = list(summary["errors"].values())
    assert any("is full (No space left on device)" in m and "free space there" in m for m in messages), messages
    assert [p for p in (small_disk / "storage").rglob(".lock*")] == []
    assert list((small_disk / "storage" / "runs").glob("*")) == []
    (small_disk / "filler").unlink()
    rerun = mocapflow("run", "--json", cwd=project)
    assert last_json(rerun)["failed"] == [] and "lost the race" not in rerun.stderr
    assert check_scaled_values(project, small_disk / "storage") == 2


def test_an_empty_takeover_claim_is_stale(tmp_path):
    version = tmp_path / "s" / "k"
    version.mkdir(parents=True)
    stale = {"host": "otherhost", "pid": 4242, "started": 1.0, "run_pid": 4242, "run": "s/seq", "token": "t0",
             "lease_s": 10.0, "renewed": time.time() - 30}
    (version / ".lock").write_text(json.dumps(stale))
    claim = version / ".lock.takeover-t0"
    claim.write_text("")  # as a full disk leaves it
    os.utime(claim, (time.time() - 5, time.time() - 5))
    with Store(str(tmp_path)).lock("s", "k", "s/seq"):
        assert json.loads((version / ".lock").read_text())["host"] != "otherhost"
    assert sorted(p.name for p in version.iterdir()) == []


# ---- 6. malformed foreign locks ------------------------------------------------------------------------------
@pytest.mark.parametrize("field,value,problem", [
    ("lease_s", float("nan"), "lease_s nan is not a positive number of seconds"),
    ("lease_s", -5.0, "lease_s -5.0 is not a positive number of seconds"),
    ("renewed", "future", "s in the future"),
])
def test_a_malformed_foreign_lock_is_stale_and_a_warning_says_so(tmp_path, caplog, field, value, problem):
    version = tmp_path / "s" / "k"
    version.mkdir(parents=True)
    info = {"host": "otherhost", "pid": 4242, "started": 1.0, "run_pid": 4242, "run": "s/seq", "token": "t1",
            "lease_s": 60.0, "renewed": time.time()}
    info[field] = time.time() + 10 ** 6 if value == "future" else value
    (version / ".lock").write_text(json.dumps(info))  # NaN as JSON's NaN, as Python writes it
    with caplog.at_level(logging.WARNING, logger="mocapflow.pipeline.locks"):
        with Store(str(tmp_path)).lock("s", "k", "s/seq"):
            assert json.loads((version / ".lock").read_text())["token"] != "t1"
    warnings = [r.getMessage() for r in caplog.records if "malformed" in r.getMessage()]
    assert warnings and problem in warnings[0] and "treating it as stale" in warnings[0], warnings
    assert not (version / ".lock").exists()

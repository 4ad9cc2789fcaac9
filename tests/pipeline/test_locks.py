"""Leased locks: a lock of another host is taken over once its lease ran out and not before, the holder's
heartbeat keeps a long-held lock fresh, and contenders racing for one stale lock never both win."""

from __future__ import annotations

import json
import multiprocessing
import os
import re
import shutil
import time
import uuid

import pytest

from conftest import assert_same_artifacts, last_json, mocapflow, read_artifacts
from mocapflow.pipeline.errors import LockError, StorageError
from mocapflow.pipeline.locks import LEASE_ENV, lease_seconds
from mocapflow.pipeline.storage import Store


def foreign_lock(path, *, renewed_ago: float | None, lease_s: float | None = None) -> dict:
    """A lock written by a process of another host; without ``renewed_ago``, as locks were written before leases
    (no renewal time)."""
    info = {"host": "otherhost", "pid": 4242, "started": 1.0, "run_pid": 4242, "since": "2024-01-01T00:00:00",
            "run": "scaled/seqA/cam0", "token": uuid.uuid4().hex}
    if renewed_ago is not None:
        info.update(renewed=time.time() - renewed_ago, lease_s=lease_s)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(info))
    return info


def lock_leftovers(root) -> list:
    return sorted(str(p) for p in root.rglob(".lock*"))


def scaled_version(toy_run):
    """A project after a clean run (the shared toy run of one sequence), that run's artifacts, and one ``scaled``
    version emptied as if a worker of another host had died right after taking its lock."""
    project, _ = toy_run(sequences=("seqA",))
    clean = read_artifacts(project / "storage")
    version = sorted((project / "storage" / "scaled").iterdir())[0]
    shutil.rmtree(version)
    version.mkdir()
    return project, clean, version


@pytest.mark.parametrize("written", ["with a lease", "before leases"])
def test_a_lock_of_another_host_whose_lease_expired_is_taken_over(toy_run, monkeypatch, written):
    project, clean, version = scaled_version(toy_run)
    if written == "with a lease":
        foreign_lock(version / ".lock", renewed_ago=5.0, lease_s=2.0)
    else:  # no renewal time: the file's age against $MOCAPFLOW_LOCK_LEASE_S
        foreign_lock(version / ".lock", renewed_ago=None)
        os.utime(version / ".lock", (time.time() - 5.0, time.time() - 5.0))
        monkeypatch.setenv(LEASE_ENV, "2")
    summary = last_json(mocapflow("run", "--json", cwd=project))
    [partition] = summary["executed"]  # only the partition behind the lock: its readers' keys did not change
    assert partition.startswith("scaled/seqA/") and summary["regions"][partition] == 5 and summary["failed"] == []
    assert_same_artifacts(read_artifacts(project / "storage"), clean)
    assert lock_leftovers(project / "storage") == []


def test_a_lock_of_another_host_with_a_live_lease_is_not_taken_over(toy_run):
    project, _, version = scaled_version(toy_run)
    held = foreign_lock(version / ".lock", renewed_ago=1.0, lease_s=600.0)
    before = (version / ".lock").read_bytes()
    proc = mocapflow("run", "--json", "--keep-going", cwd=project, check=False)
    summary = last_json(proc)
    assert proc.returncode == 1
    [(partition, message)] = summary["errors"].items()
    assert partition.startswith("scaled/seqA/")
    assert "is being written by another run" in message and "wait for it to finish" in message
    assert f"host otherhost pid {held['run_pid']}" in message
    expires = re.search(r"expires in (\d+)", message)  # 600 s less the second and the run's own start
    assert expires and 500 < int(expires.group(1)) < 600
    assert LEASE_ENV in message and str(version / ".lock") in message
    assert (version / ".lock").read_bytes() == before  # untouched
    assert not (version / "_COMPLETE").exists()


def test_the_heartbeat_keeps_a_long_held_lock_fresh(tmp_path):
    store = Store(str(tmp_path))
    path = tmp_path / "s" / "k" / ".lock"
    lease = 0.6
    with store.lock("s", "k", "s/seq", lease_s=lease):
        first = json.loads(path.read_text())
        ages = []
        for _ in range(12):  # 2.4 s: four leases
            time.sleep(0.2)
            held = json.loads(path.read_text())
            assert held["token"] == first["token"] and held["lease_s"] == lease
            ages.append(time.time() - held["renewed"])
            with pytest.raises(LockError, match="is being written by another run"):
                with Store(str(tmp_path)).lock("s", "k", "s/seq other", lease_s=lease):
                    pass
        assert max(ages) < lease
        assert json.loads(path.read_text())["renewed"] > first["renewed"] + 3 * lease
    assert not path.exists()


def test_a_holder_whose_lock_was_taken_over_is_told_on_exit(tmp_path):
    store = Store(str(tmp_path))
    path = tmp_path / "s" / "k" / ".lock"
    with pytest.raises(LockError, match=r"another run took over .*\.lock while this one held it"):
        with store.lock("s", "k", "s/seq", lease_s=0.3):
            thief = foreign_lock(path, renewed_ago=0.0, lease_s=60.0)  # as a takeover after a stall would leave it
            time.sleep(0.3)  # a renewal notices
    assert json.loads(path.read_text())["token"] == thief["token"]  # the new holder's lock is left alone


def test_a_claim_left_by_a_dead_contender_does_not_block_the_takeover(tmp_path):
    path = tmp_path / "s" / "k" / ".lock"
    stale = foreign_lock(path, renewed_ago=30.0, lease_s=10.0)
    foreign_lock(tmp_path / "s" / "k" / f".lock.takeover-{stale['token']}", renewed_ago=30.0, lease_s=10.0)
    with Store(str(tmp_path)).lock("s", "k", "s/seq"):
        assert json.loads(path.read_text())["host"] != "otherhost"
    assert lock_leftovers(tmp_path) == []


def test_a_claim_of_a_live_contender_makes_the_others_back_off(tmp_path):
    path = tmp_path / "s" / "k" / ".lock"
    stale = foreign_lock(path, renewed_ago=30.0, lease_s=10.0)
    foreign_lock(tmp_path / "s" / "k" / f".lock.takeover-{stale['token']}", renewed_ago=0.0, lease_s=10.0)
    with pytest.raises(LockError, match=r"partition s/seq: lost the race for .*\.lock to another run; retry"):
        with Store(str(tmp_path)).lock("s", "k", "s/seq"):
            pass
    assert json.loads(path.read_text())["token"] == stale["token"]


def _contend(root: str, barrier, results, done) -> None:
    """One contender: take the lock (after the barrier, so both read the stale lock before either claims it),
    report, and hold it until the parent has both reports."""
    from mocapflow.pipeline import locks

    real = locks.LeasedLock._take_over

    def slow_take_over(self, stale):
        time.sleep(0.05)  # both contenders have read the stale lock by now
        return real(self, stale)

    locks.LeasedLock._take_over = slow_take_over
    barrier.wait()
    try:
        with Store(root).lock("s", "k", f"s/seq {os.getpid()}"):
            results.put(("won", os.getpid()))
            done.wait(30)
    except LockError as exc:
        results.put(("lost", str(exc)))


def test_two_processes_racing_for_one_stale_lock_never_both_win(tmp_path):
    ctx = multiprocessing.get_context("spawn")
    for attempt in range(4):
        root = tmp_path / f"r{attempt}"
        foreign_lock(root / "s" / "k" / ".lock", renewed_ago=30.0, lease_s=10.0)
        barrier, results, done = ctx.Barrier(2), ctx.Queue(), ctx.Event()
        procs = [ctx.Process(target=_contend, args=(str(root), barrier, results, done)) for _ in range(2)]
        for p in procs:
            p.start()
        outcomes = [results.get(timeout=60) for _ in procs]
        done.set()
        for p in procs:
            p.join(30)
            assert p.exitcode == 0
        assert sorted(kind for kind, _ in outcomes) == ["lost", "won"], outcomes
        [message] = [m for kind, m in outcomes if kind == "lost"]
        assert "lost the race" in message or "is being written by another run" in message
        assert lock_leftovers(root) == []


def test_a_bad_lease_setting_is_a_clear_error(monkeypatch):
    monkeypatch.setenv(LEASE_ENV, "soon")
    with pytest.raises(StorageError, match=f"{LEASE_ENV}='soon' is not a number of seconds"):
        lease_seconds()
    monkeypatch.setenv(LEASE_ENV, "0")
    with pytest.raises(StorageError, match="must be a positive number"):
        lease_seconds()
    monkeypatch.setenv(LEASE_ENV, "90")
    assert lease_seconds() == 90.0

"""The engine on an object store: run, kill -9 and resume, verify, gc and locks against an S3 server on 127.0.0.1.

The server is moto's (``moto[server]``, in the ``test`` extra), started in this process on a free port; the engine
reaches it through s3fs, with the toy catalog's storage root at ``s3://<bucket>/<prefix>``. Credentials and the
endpoint travel in the environment of the `mocapflow` subprocesses (``AWS_ACCESS_KEY_ID``, ``AWS_SECRET_ACCESS_KEY``,
``AWS_ENDPOINT_URL``), never in the catalog, and the tests check that no stored object, log or output holds them.
Every S3 run is compared with the same project's local run (``toy_run``): the same cache keys and chunk bytes.

Where moto or s3fs is missing, or the server cannot start, the tests skip saying so; in CI (``CI=true``,
``MOCAPFLOW_REQUIRE_SHARED=1`` or ``MOCAPFLOW_REQUIRE_OBJECT_STORE=1``) they fail instead.
"""

from __future__ import annotations

import json
import logging
import os
import signal
import subprocess
import sys
import threading
import time
import uuid
from dataclasses import dataclass
from pathlib import Path

import pytest

from conftest import env_with_plugins, last_json

from mocapflow.pipeline.errors import LockError
from mocapflow.pipeline.integrity import is_chunk
from mocapflow.pipeline.locks import LeasedLock, conditional_create
from mocapflow.pipeline.storage import Store

REQUIRE = "MOCAPFLOW_REQUIRE_OBJECT_STORE"
REGION = "eu-west-1"
STAGES_TOTAL = 12  # the toy catalog's partitions: frames 2, scaled 4, diffed 4, summed 2


def _required() -> bool:
    """Whether a missing server is an error here (CI) rather than a skip."""
    return (os.environ.get(REQUIRE) == "1" or os.environ.get("CI", "").lower() == "true"
            or os.environ.get("MOCAPFLOW_REQUIRE_SHARED") == "1")


def _unavailable(why: str):
    if _required():
        pytest.fail(f"{why}; the object-store tests must run here (CI=true, MOCAPFLOW_REQUIRE_SHARED=1 or {REQUIRE}=1): "
                    "install the test extra, pip install -e '.[test]'")
    pytest.skip(why)


@dataclass
class S3:
    """The test's S3 server: its endpoint, a bucket, the credentials (only in the subprocesses' environment) and an
    s3fs client of its own."""

    endpoint: str
    bucket: str
    key_id: str
    secret: str
    fs: object

    def url(self, prefix: str) -> str:
        return f"s3://{self.bucket}/{prefix}"

    def env(self, **more: str) -> dict:
        """The `mocapflow` subprocesses' environment: the plugins, this server and its credentials, and nothing of
        the developer's own AWS or fsspec settings."""
        base = {k: v for k, v in env_with_plugins().items() if not k.startswith(("AWS_", "FSSPEC_"))}
        return {**base, "AWS_ACCESS_KEY_ID": self.key_id, "AWS_SECRET_ACCESS_KEY": self.secret,
                "AWS_DEFAULT_REGION": REGION, "AWS_ENDPOINT_URL": self.endpoint, "AWS_EC2_METADATA_DISABLED": "true",
                "AWS_CONFIG_FILE": os.devnull, "AWS_SHARED_CREDENTIALS_FILE": os.devnull, **more}

    def objects(self, prefix: str, pattern: str = "**") -> list[str]:
        """The objects under ``prefix`` (``pattern``: those it matches)."""
        if pattern == "**":
            return sorted(self.fs.find(f"{self.bucket}/{prefix}"))
        return sorted(self.fs.glob(f"{self.bucket}/{prefix}/{pattern}"))

    def complete(self, prefix: str) -> list[str]:
        """stage/key of every complete version under ``prefix``."""
        return sorted("/".join(p.split("/")[-3:-1]) for p in self.fs.glob(f"{self.bucket}/{prefix}/*/*/_COMPLETE"))

    def locks(self, prefix: str, stage: str = "*") -> list[str]:
        return self.fs.glob(f"{self.bucket}/{prefix}/{stage}/*/.lock")


@pytest.fixture(scope="module")
def s3():
    try:
        import s3fs
        from moto.server import ThreadedMotoServer
    except ImportError as exc:
        _unavailable(f"the object-store tests need moto[server] and s3fs ({exc})")
    logging.getLogger("werkzeug").setLevel(logging.ERROR)  # the server's line per request
    server = ThreadedMotoServer(ip_address="127.0.0.1", port=0, verbose=False)
    try:
        server.start()
        host, port = server.get_host_and_port()
    except Exception as exc:  # noqa: BLE001  (whatever keeps it from serving)
        _unavailable(f"moto's S3 server did not start on 127.0.0.1 ({type(exc).__name__}: {exc})")
    endpoint = f"http://{host}:{port}"
    key_id, secret = f"AKIA{uuid.uuid4().hex[:16].upper()}", f"never-stored-{uuid.uuid4().hex}"
    fs = s3fs.S3FileSystem(key=key_id, secret=secret, endpoint_url=endpoint, use_listings_cache=False,
                           client_kwargs={"region_name": REGION})
    bucket = f"mocapflow-{uuid.uuid4().hex[:8]}"
    try:
        fs.mkdir(bucket)
        yield S3(endpoint, bucket, key_id, secret, fs)
    finally:
        server.stop()


def mocapflow_s3(s3: S3, *args, cwd: Path, check: bool = True, env: dict | None = None,
                 timeout: float = 300) -> subprocess.CompletedProcess:
    """The real CLI in a subprocess, with the S3 server's environment (``env``: more variables)."""
    proc = subprocess.run([sys.executable, "-m", "mocapflow.cli.commands", *map(str, args)], cwd=cwd,
                          env=s3.env(**(env or {})), capture_output=True, text=True, timeout=timeout)
    if check and proc.returncode != 0:
        raise AssertionError(f"mocapflow {' '.join(map(str, args))} exited {proc.returncode}\n"
                             f"stdout:\n{proc.stdout}\nstderr:\n{proc.stderr}")
    assert s3.secret not in proc.stdout + proc.stderr and s3.key_id not in proc.stdout + proc.stderr
    return proc


def poll(predicate, what: str, timeout: float = 180.0, every: float = 0.5) -> None:
    """Wait until ``predicate()`` holds, looking every ``every`` seconds (each look lists the bucket: the server the
    run writes to answers it); AssertionError naming ``what`` after ``timeout`` seconds."""
    deadline = time.time() + timeout
    while not predicate():
        if time.time() > deadline:
            raise AssertionError(f"{what} not met within {timeout:.0f} s")
        time.sleep(every)


def on_s3(s3: S3, project: Path, prefix: str) -> Path:
    """Point the toy project's catalog (its local run is the reference) at ``s3://<bucket>/<prefix>``."""
    catalog = project / "catalog.yaml"
    text = catalog.read_text()
    assert "root: storage/" in text
    catalog.write_text(text.replace("root: storage/", f"root: {s3.url(prefix)}"))
    return project


def upload(s3: S3, project: Path, prefix: str) -> None:
    """The project's local store, byte for byte, under ``prefix`` (to start a test from a finished run)."""
    files = [p for p in (project / "storage").rglob("*") if p.is_file()]
    s3.fs.put([str(p) for p in files],
              [f"{s3.bucket}/{prefix}/{p.relative_to(project / 'storage').as_posix()}" for p in files])


def s3_artifacts(s3: S3, prefix: str) -> dict:
    """(stage, key) -> {object under data.zarr: its bytes, chunks only} for every complete version on S3; the
    metadata's names are kept (their bytes hold the lineage's times)."""
    out = {}
    for version in s3.complete(prefix):
        base = f"{s3.bucket}/{prefix}/{version}/data.zarr/"
        names = [p[len(base):] for p in s3.fs.find(base)]
        chunks = s3.fs.cat([base + n for n in names if is_chunk(n)])
        out[tuple(version.split("/"))] = {n: (chunks[base + n] if is_chunk(n) else None) for n in names}
    return out


def local_artifacts(root: Path) -> dict:
    out = {}
    for done in root.glob("*/*/_COMPLETE"):
        base = done.parent / "data.zarr"
        out[(done.parent.parent.name, done.parent.name)] = {
            p.relative_to(base).as_posix(): (p.read_bytes() if is_chunk(p.relative_to(base).as_posix()) else None)
            for p in base.rglob("*") if p.is_file()}
    return out


def assert_same_as_local(s3: S3, prefix: str, project: Path) -> None:
    """The versions under ``prefix`` are the project's local run's: the same cache keys, objects and chunk bytes."""
    remote, local = s3_artifacts(s3, prefix), local_artifacts(project / "storage")
    assert len(local) == STAGES_TOTAL
    assert sorted(remote) == sorted(local), "the S3 run made other cache keys than the local run"
    for version, objects in local.items():
        assert remote[version].keys() == objects.keys(), version
        for name, data in objects.items():
            assert remote[version][name] == data, f"{version} {name} differs from the local run's"


def assert_no_secret_stored(s3: S3, prefix: str, project: Path) -> None:
    """Neither credential is in the catalog or in any object under ``prefix`` (the run logs among them)."""
    catalog = (project / "catalog.yaml").read_text()
    assert s3.secret not in catalog and s3.key_id not in catalog
    paths = s3.objects(prefix)
    assert any(p.split("/")[-2] == "logs" for p in paths), "the run log was not written to the store"
    for path, data in s3.fs.cat(paths).items():
        assert s3.secret.encode() not in data and s3.key_id.encode() not in data, f"a credential is stored in {path}"


def version_of(s3: S3, prefix: str, partition: str) -> str:
    """stage/key of the complete version of ``partition`` (e.g. scaled/seqA/cam0) under ``prefix``."""
    for version in s3.complete(prefix):
        lineage = json.loads(s3.fs.cat_file(f"{s3.bucket}/{prefix}/{version}/lineage.json"))
        if lineage["partition"] == partition:
            return version
    raise AssertionError(f"no complete version of {partition} under {prefix}")


# ---- (a) a run, and a second that computes nothing -----------------------------------------------------------------
def test_run_on_s3_writes_the_local_bytes_and_a_second_run_computes_nothing(s3, toy_run):
    project, _ = toy_run(frames=8)  # two regions a partition: fewer objects for the S3 server to serve
    on_s3(s3, project, "plain")
    first = last_json(mocapflow_s3(s3, "run", "--json", cwd=project))
    assert first["failed"] == [] and len(first["executed"]) == STAGES_TOTAL
    assert_same_as_local(s3, "plain", project)
    second = mocapflow_s3(s3, "run", "--json", cwd=project)
    summary = last_json(second)
    assert summary["executed"] == [] and len(summary["cached"]) == STAGES_TOTAL and summary["failed"] == []
    assert f"log {s3.url('plain')}/logs/run-" in second.stdout
    assert s3.locks("plain") == [] and s3.objects("plain", "runs/*") == []  # no lock nor lease left behind
    assert_no_secret_stored(s3, "plain", project)


# ---- (b) kill -9 part-way, resume --------------------------------------------------------------------------------
def test_run_killed_after_its_first_artifact_resumes_to_the_same_keys_and_bytes(s3, toy_run, tmp_path):
    project, _ = toy_run(frames=8)  # two regions a partition: fewer objects for the S3 server to serve
    on_s3(s3, project, "killed")
    hold = tmp_path / "hold"  # while it exists, every scale task waits inside its partition, holding its lock
    hold.write_text("")
    with open(tmp_path / "killed.out", "w") as out:
        # TMPDIR: where a run on an object store keeps its log until it ends (a killed one leaves it)
        proc = subprocess.Popen([sys.executable, "-m", "mocapflow.cli.commands", "run", "--json", "--workers", "2"],
                                cwd=project, env=s3.env(TOY_HOLD_WHILE=str(hold), TMPDIR=str(tmp_path)),
                                stdout=out, stderr=subprocess.STDOUT, start_new_session=True)
        try:
            poll(lambda: s3.complete("killed") and len(s3.locks("killed", "scaled")) == 2,
                 "the first complete artifact and both workers inside a scaled partition")
        finally:
            os.killpg(proc.pid, signal.SIGKILL)  # the whole run, its workers too, as a crash takes it
            proc.wait()
    hold.unlink()
    done = s3.complete("killed")
    assert 1 <= len(done) < STAGES_TOTAL, f"the run must be killed part-way ({done})"
    assert len(s3.locks("killed", "scaled")) == 2, "the killed run left its locks behind"

    resumed = mocapflow_s3(s3, "run", "--json", cwd=project)
    summary = last_json(resumed)
    assert summary["failed"] == [] and summary["executed"], summary
    assert not set(summary["executed"]) & {f"frames/{s}" for s in ("seqA", "seqB")}, "a finished artifact was redone"
    assert_same_as_local(s3, "killed", project)
    assert s3.locks("killed") == []  # the dead run's locks were taken over, and released


# ---- (c) verify ---------------------------------------------------------------------------------------------------
def test_verify_on_s3_passes_then_reports_a_corrupted_chunk_and_the_run_repairs_it(s3, toy_run):
    project, _ = toy_run(frames=8)  # two regions a partition: fewer objects for the S3 server to serve
    upload(s3, project, "verify")
    on_s3(s3, project, "verify")
    assert "12 intact, 0 damaged" in mocapflow_s3(s3, "verify", cwd=project).stdout

    version = version_of(s3, "verify", "scaled/seqA/cam0")
    chunk = f"{s3.bucket}/verify/{version}/data.zarr/value/c/0/1/0/0"  # view 0, frames 4-7
    data = bytearray(s3.fs.cat_file(chunk))
    data[len(data) // 2] ^= 0xFF
    s3.fs.pipe_file(chunk, bytes(data))
    damaged = mocapflow_s3(s3, "verify", cwd=project, check=False)
    assert damaged.returncode == 1
    assert f"DAMAGED scaled/seqA/cam0 ({version}): 1 chunk(s), in 00000004-00000008" in damaged.stdout
    assert "11 intact, 1 damaged" in damaged.stdout
    assert s3.fs.exists(f"{s3.bucket}/verify/{version}/_DAMAGED")

    repaired = last_json(mocapflow_s3(s3, "run", "--json", cwd=project))
    assert repaired["executed"] == ["scaled/seqA/cam0"] and repaired["regions"] == {"scaled/seqA/cam0": 1}
    assert_same_as_local(s3, "verify", project)


# ---- (d) gc -------------------------------------------------------------------------------------------------------
def test_gc_on_s3_deletes_an_orphaned_version_and_keeps_the_live_ones(s3, toy_run):
    project, _ = toy_run(frames=8)  # two regions a partition: fewer objects for the S3 server to serve
    upload(s3, project, "gc")
    on_s3(s3, project, "gc")
    live = s3.complete("gc")
    other = last_json(mocapflow_s3(s3, "run", "--json", "--set", "stages.scaled.params.factor=4", "--only", "scaled",
                                   "--sequences", "seqA", cwd=project))
    assert sorted(other["executed"]) == ["scaled/seqA/cam0", "scaled/seqA/cam1"]
    orphans = sorted(set(s3.complete("gc")) - set(live))
    assert len(orphans) == 2

    swept = mocapflow_s3(s3, "gc", cwd=project).stdout
    assert "2 unreferenced version(s) deleted, 0 kept" in swept
    for orphan in orphans:
        assert f"deleted {orphan} (scaled/seqA/" in swept
        assert s3.fs.glob(f"{s3.bucket}/gc/{orphan}/**") == [], f"{orphan} left objects behind"
    assert s3.complete("gc") == live
    assert_same_as_local(s3, "gc", project)  # the live versions, intact


# ---- locks: the conditional create (two whole runs racing: tests/pipeline/test_concurrency.py, locally) ----
def test_s3_lock_create_is_conditional_so_one_of_many_contenders_wins(s3, monkeypatch):
    store = Store(s3.url("race"))  # the engine's own client: credentials from the environment, set here for it
    assert conditional_create(store.fs), "s3fs must create with If-None-Match (s3fs >= 2024.12)"
    path = f"{s3.bucket}/race/stage/key/.lock"

    # a create that looked a hair before another run's lock landed: the server refuses it, nothing is overwritten
    other = LeasedLock(store.fs, path, False, "the other run", lease_s=60)
    other.acquire()
    with monkeypatch.context() as patch:
        patch.setattr(store.fs, "exists", lambda *args, **kwargs: False)
        late = LeasedLock(store.fs, path, False, "late", lease_s=60)
        assert not late._create(path, late.me)
    assert json.loads(store.fs.cat_file(path))["token"] == other.me["token"]
    other.release()
    assert not store.fs.exists(path)

    def race(n: int) -> list[LeasedLock]:
        barrier, won = threading.Barrier(n), []

        def contend(i: int) -> None:
            lock = LeasedLock(store.fs, path, False, f"contender {i}", lease_s=60)
            barrier.wait()
            try:
                lock.acquire()
            except LockError:
                return
            won.append(lock)

        threads = [threading.Thread(target=contend, args=(i,)) for i in range(n)]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
        return won

    won = race(8)
    assert len(won) == 1, f"{len(won)} contenders created the same lock"
    won[0].release()
    assert not store.fs.exists(path)

    # a stale lock (another host's, its lease long run out) is taken over by exactly one contender
    stale = {"host": "elsewhere", "pid": 1, "started": 0.0, "run": "gone", "token": "f" * 32, "lease_s": 60,
             "renewed": time.time() - 3600}
    store.fs.pipe_file(path, json.dumps(stale).encode())
    won = race(8)
    assert len(won) == 1, f"{len(won)} contenders took over the same stale lock"
    assert json.loads(store.fs.cat_file(path))["token"] == won[0].me["token"]
    won[0].release()
    assert store.fs.glob(f"{s3.bucket}/race/stage/key/.lock*") == []


@pytest.fixture(autouse=True)
def _credentials_for_this_process(request, monkeypatch):
    """The engine's clients in this process (test_s3_lock_...) read the server and credentials from the
    environment, as the subprocesses do."""
    if "s3" in request.fixturenames:
        s3 = request.getfixturevalue("s3")
        for name, value in s3.env().items():
            if name.startswith("AWS_"):
                monkeypatch.setenv(name, value)

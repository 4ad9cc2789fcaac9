"""Leased locks on a storage root shared by several processes and hosts.

A lock is a small JSON file naming its holder (host, pid, run, a random token) and when the holder last
renewed it. The holder renews it every ``lease / HEARTBEATS_PER_LEASE`` seconds from a daemon thread; a lock
is *stale* when its lease ran out (on any host), or at once when its holder is a process of this host that
no longer runs. A stale lock is taken over, never deleted and recreated:

1. the contender claims the stale generation by creating ``<lock>.takeover-<token>`` exclusively (the token
   is the stale holder's, so every generation has its own claim and a late contender cannot reuse an old one);
2. holding the claim it reads the lock again: still that token and still stale, or it backs off;
3. it writes its own lock beside it and moves it over the lock with one ``os.replace``, then drops the claim.

The holder's renewals and its release take the same claim on their own token, so a takeover and a renewal
never interleave: whichever comes second sees the other's result. A claim whose maker died (a claim lives a
few milliseconds) is stale by the same rules and is claimed in turn (``<claim>-<token>``).

A lock also names the run it was taken for and the scheduler's name of the worker (``run_id``, ``worker``): when
the scheduler retries the task of a worker it lost, the retry, of the same run, asks the scheduler whether that
worker still lives and takes its lock over at once if not, on any host (``working_for``). A lock whose fields are
impossible (a lease that is not a positive number, a renewal further ahead than a lease) is stale, with a warning;
so is a lock or claim file still unreadable a second after it was created (its writer failed, e.g. on a full disk,
where no claim is left behind).

Locally this rests on ``O_CREAT | O_EXCL`` and ``os.replace`` (atomic on POSIX, on NFSv3+ and on SMB).
An object store needs a conditional write for the same guarantee: create-if-absent for the claim and the lock.
On S3 (s3fs) the create is a PUT with ``If-None-Match: *`` (``conditional_create``), which the server refuses where
the object exists, so exactly one contender creates a lock or a claim, as ``O_EXCL`` does; every replacement of a
lock (a renewal, a takeover, a release) happens under the claim on its generation, so it needs no compare-and-swap
of its own, and a PUT replaces an object whole. S3 reads are strongly consistent after writes (AWS since 2020;
MinIO; moto), and the store reads markers and locks without a listings cache (storage.py). A server that ignores
``If-None-Match`` (some older S3-compatible ones) and any other fsspec filesystem get a look, then a write, then
a read back, which narrows the race but does not close it.

Clocks: the lease is measured from the renewal time the holder writes, on the reader's clock, so the hosts'
clocks must agree to well within the lease (NTP keeps them within milliseconds).
"""

from __future__ import annotations

import contextvars
import errno
import inspect
import json
import logging
import math
import multiprocessing
import os
import socket
import threading
import time
import uuid
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Callable, Iterator

import psutil

from mocapflow.pipeline.errors import LockError, StorageError

log = logging.getLogger(__name__)

LEASE_ENV = "MOCAPFLOW_LOCK_LEASE_S"
HOST_ENV = "MOCAPFLOW_HOSTNAME"  # the host name locks record (tests simulate a second host with it)
# 60 s lease, renewed every 10 s: a holder misses five renewals in a row before anyone may take its lock over,
# which rides out a long garbage-collection pause, a swapping host or an NFS server that stalls for tens of seconds
# (a hard mount retries every 6 s by default), while a partition whose worker died on another host waits at most a
# minute for the run that takes it over. Same-host holders that died are taken over at once.
DEFAULT_LEASE_S = 60.0
HEARTBEATS_PER_LEASE = 6
CLAIM_WAIT_S = 2.0  # how long a holder waits for a contender's claim on its lock (held for milliseconds)
UNREADABLE = "unreadable"  # the token of a lock file whose contents cannot be parsed
# A lock or claim file is created empty and written at once; one still unreadable after this long was left by a
# writer that failed (a full disk) or died in between, and is stale.
UNREADABLE_GRACE_S = 1.0


def hostname() -> str:
    """This host's name as locks record it: ``$MOCAPFLOW_HOSTNAME`` or the system's."""
    return os.environ.get(HOST_ENV) or socket.gethostname()


@dataclass(frozen=True)
class RunContext:
    """Who takes locks in this thread: the run (``run_id``), the scheduler's name for this worker (``worker``), and
    how to ask the scheduler which workers still live (``live_workers``: their names)."""

    run_id: str
    worker: str | None = None
    live_workers: Callable[[], set[str]] | None = None


_CONTEXT: contextvars.ContextVar[RunContext | None] = contextvars.ContextVar("mocapflow_run", default=None)


@contextmanager
def working_for(context: RunContext) -> Iterator[None]:
    """Locks taken in the enclosed code carry ``context``'s run and worker; a lock of this run held by a worker that
    the scheduler reports dead is taken over at once (the scheduler retries its task on another worker)."""
    token = _CONTEXT.set(context)
    try:
        yield
    finally:
        _CONTEXT.reset(token)


def lease_seconds() -> float:
    """The lease of new locks: ``$MOCAPFLOW_LOCK_LEASE_S`` or ``DEFAULT_LEASE_S``."""
    raw = os.environ.get(LEASE_ENV)
    if raw is None or raw.strip() == "":
        return DEFAULT_LEASE_S
    try:
        value = float(raw)
    except ValueError as exc:
        raise StorageError(f"{LEASE_ENV}={raw!r} is not a number of seconds; set it to a positive number "
                           f"(default {DEFAULT_LEASE_S:g})") from exc
    if not value > 0:
        raise StorageError(f"{LEASE_ENV}={raw!r} must be a positive number of seconds (default {DEFAULT_LEASE_S:g})")
    return value


class LeasedLock:
    """One lock file ``path`` on the fsspec filesystem ``fs`` (``local``: a local or mounted folder)."""

    def __init__(self, fs, path: str, local: bool, label: str, lease_s: float | None = None):
        self.fs, self.path, self.local, self.label = fs, path, local, label
        self.me = holder_info(label, lease_seconds() if lease_s is None else lease_s)
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self.lost = False

    # ---- the holder's side -------------------------------------------------------------
    def acquire(self) -> None:
        """Take the lock, taking over a stale one; LockError while another holder's lease runs."""
        for _ in range(3):
            if self._create(self.path, self.me):
                break
            holder = self._read(self.path)
            if holder is None:
                continue  # released meanwhile: create again
            if not self._stale(self.path, holder):
                raise LockError(busy_message(self.label, self.path, holder))
            if self._take_over(holder):
                break
        else:
            raise LockError(f"partition {self.label}: lost the race for {self.path} to another run; retry")
        self._thread = threading.Thread(target=self._beat, name=f"lease {self.label}", daemon=True)
        self._thread.start()

    def release(self) -> None:
        """Stop renewing and delete the lock if it is still ours."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=CLAIM_WAIT_S + 1.0)
        if self._read(self.path) is None:
            return  # deleted, with its version folder (mocapflow gc)
        try:
            claims = self._claim_waiting(self.me["token"])
        except FileNotFoundError:
            return  # the version folder was deleted meanwhile
        except OSError as exc:
            if not no_space(exc):
                raise
            # no room for a claim (a full disk); a live lock is never taken over, so deleting ours is safe
            if _token(self._read(self.path)) == self.me["token"]:
                self.fs.rm_file(self.path)
            return
        if claims is None:
            log.warning("%s: a contender held the claim on %s for %.0f s; left the lock to expire",
                        self.label, self.path, CLAIM_WAIT_S)
            return
        try:
            if _token(self._read(self.path)) == self.me["token"]:
                self.fs.rm_file(self.path)
        finally:
            self._drop(claims)

    def renew(self) -> bool:
        """Write a fresh renewal time; False once the lock is no longer ours (another run took it over)."""
        claims = self._claim_waiting(self.me["token"])
        if claims is None:
            return True  # a contender is looking at our lock; it sees our last renewal, and we retry next beat
        try:
            if _token(self._read(self.path)) != self.me["token"]:
                return False
            self._replace(self.path, self.me)
            return True
        finally:
            self._drop(claims)

    def _beat(self) -> None:
        interval = float(self.me["lease_s"]) / HEARTBEATS_PER_LEASE
        while not self._stop.wait(interval):
            try:
                if not self.renew():
                    self.lost = True
                    log.error("%s: the lock %s was taken over by another run (no renewal for a whole lease)",
                              self.label, self.path)
                    return
            except OSError as exc:
                log.warning("%s: could not renew %s (%s); retrying in %.1f s", self.label, self.path, exc, interval)

    # ---- the contender's side ------------------------------------------------------------
    def _take_over(self, stale: dict) -> bool:
        """Replace the stale lock ``stale`` with ours, atomically; False if another contender or the holder
        got there first."""
        claims = self._claim(_token(stale))
        if claims is None:
            return False
        try:
            current = self._read(self.path)
            if current is None or _token(current) != _token(stale) or not self._stale(self.path, current):
                return False
            self._replace(self.path, self.me)
        finally:
            self._drop(claims)
        log.warning("%s: took over the stale lock %s of %s", self.label, self.path, describe(stale))
        return True

    def _claim(self, token: str) -> list[str] | None:
        """The exclusive claim on the lock generation ``token`` (and the stale claims passed on the way, to drop
        with it), or None while another live contender holds it."""
        claim, passed = f"{self.path}.takeover-{token}", []
        for _ in range(4):
            if self._create(claim, self.me):
                return [claim, *passed]
            other = self._read(claim)
            if other is None or not self._stale(claim, other):
                return None
            passed.append(claim)
            claim = f"{claim}-{_token(other)}"
        return None

    def _claim_waiting(self, token: str) -> list[str] | None:
        deadline = time.monotonic() + CLAIM_WAIT_S
        while True:
            claims = self._claim(token)
            if claims is not None or time.monotonic() > deadline:
                return claims
            time.sleep(0.01)

    def _stale(self, path: str, holder: dict) -> bool:
        """Whether ``holder`` (read from ``path``) has lost its claim: dead on this host, fenced by its own run (a
        worker the scheduler reports dead), impossible (see ``impossible``), or its lease ran out."""
        if not holder:  # unreadable: created but never written (a full disk, a writer that died in between)
            return time.time() - self._mtime(path) > UNREADABLE_GRACE_S
        if holder.get("host") == hostname() and not process_alive(holder):
            return True
        problem = impossible(holder)
        if problem is not None:
            log.warning("%s: the lock %s of %s is malformed (%s); treating it as stale", self.label, path,
                        describe(holder), problem)
            return True
        renewed = _number(holder, "renewed")
        if renewed is None:  # written by an older release: the file's modification time
            renewed = self._mtime(path)
        lease = _number(holder, "lease_s") or lease_seconds()
        return time.time() - renewed > lease or _fenced(self.label, path, holder)

    # ---- files -----------------------------------------------------------------------------
    def _create(self, path: str, info: dict) -> bool:
        """Create ``path`` holding ``info`` if it does not exist; False if it does."""
        data = _encode(info)
        if self.local:
            try:
                fd = os.open(path, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o644)
            except FileExistsError:
                return False
            try:
                with os.fdopen(fd, "wb") as fh:
                    fh.write(data)
            except OSError:  # a full disk: leave no empty claim or lock behind
                _unlink_quietly(path)
                raise
            return True
        if conditional_create(self.fs):
            return _create_if_absent(self.fs, path, data)
        if self.fs.exists(path):  # best effort: no create-if-absent on this filesystem (see the module's docstring)
            return False
        self.fs.pipe_file(path, data)
        return _token(self._read(path)) == info["token"]

    def _replace(self, path: str, info: dict) -> None:
        """Put ``info`` at ``path`` in one step: readers see the old lock or the new, never a part."""
        _put(self.fs, self.local, path, _encode(info), f"{path}.{info['token']}.tmp")

    def _read(self, path: str) -> dict | None:
        """The lock at ``path``; None if there is none, {} if its contents are unreadable."""
        try:
            text = self.fs.cat_file(path)
        except FileNotFoundError:
            return None
        try:
            info = json.loads(text)
        except ValueError:
            return {}
        return info if isinstance(info, dict) else {}

    def _mtime(self, path: str) -> float:
        try:
            return self.fs.modified(path).timestamp()
        except (FileNotFoundError, NotImplementedError):
            return 0.0

    def _drop(self, claims: list[str]) -> None:
        for claim in claims:
            try:
                self.fs.rm_file(claim)
            except FileNotFoundError:
                continue


def holder_info(label: str, lease_s: float) -> dict:
    """Who takes a lock: this process (``pid``, ``started``: whether it still runs), the run it works for
    (``run_pid``: the process that started this one when this is a worker process, else this one), and its
    lease."""
    me = psutil.Process()
    parent = multiprocessing.parent_process()
    context = _CONTEXT.get()
    info = {"host": hostname(), "pid": os.getpid(), "started": me.create_time(),
            "run_pid": parent.pid if parent is not None else os.getpid(),
            "since": time.strftime("%Y-%m-%dT%H:%M:%S"), "run": label, "token": uuid.uuid4().hex,
            "lease_s": lease_s}
    if context is not None:
        info.update(run_id=context.run_id, worker=context.worker)
    return info


def impossible(holder: dict) -> str | None:
    """What makes a lock's fields impossible (a lease that is not a positive finite number, a renewal time that is
    not finite or lies further ahead than a lease: no clock that agrees within the lease writes one), or None."""
    lease, renewed = holder.get("lease_s"), holder.get("renewed")
    if lease is not None:
        value = _number(holder, "lease_s")
        if value is None or not math.isfinite(value) or value <= 0:
            return f"lease_s {lease!r} is not a positive number of seconds"
    if renewed is not None:
        value = _number(holder, "renewed")
        if value is None or not math.isfinite(value):
            return f"renewed {renewed!r} is not a time"
        ahead = value - time.time()
        if ahead > (_number(holder, "lease_s") or lease_seconds()):
            return f"renewed {ahead:.0f} s in the future"
    return None


def _fenced(label: str, path: str, holder: dict) -> bool:
    """Whether ``holder`` is a worker of this thread's own run that the run's scheduler reports dead (the scheduler
    then retries its task, here): its lock is taken over at once, on any host."""
    context = _CONTEXT.get()
    worker = holder.get("worker")
    if context is None or context.live_workers is None or not worker or holder.get("run_id") != context.run_id:
        return False
    if worker == context.worker:
        return False
    try:
        live = context.live_workers()
    except (OSError, RuntimeError, ValueError) as exc:  # no answer: leave it to the lease
        log.warning("%s: could not ask the scheduler whether worker %s lives (%s)", label, worker, exc)
        return False
    if worker in live:
        return False
    log.warning("%s: the lock %s is held by worker %s of this run, which the scheduler reports dead; taking it over",
                label, path, worker)
    return True


def conditional_create(fs) -> bool:
    """Whether ``fs`` creates an object only where none exists, in one request the server decides: S3 through an s3fs
    whose ``pipe_file`` takes ``mode="create"`` (a PUT with ``If-None-Match: *``; AWS S3, MinIO and moto honour it).
    Elsewhere a create is a look, then a write (best effort: see the module's docstring)."""
    if "s3" not in _protocols(fs):
        return False
    method = getattr(type(fs), "_pipe_file", None)
    try:
        return method is not None and "mode" in inspect.signature(method).parameters
    except (TypeError, ValueError):
        return False


def _create_if_absent(fs, path: str, data: bytes) -> bool:
    """Create the object ``path`` holding ``data`` with a conditional write; False where it exists (or a concurrent
    conditional write of it won: S3's 409 ConditionalRequestConflict)."""
    try:
        fs.pipe_file(path, data, mode="create")
    except FileExistsError:
        return False
    except OSError as exc:
        if _s3_code(exc) in ("PreconditionFailed", "ConditionalRequestConflict"):
            return False
        raise
    return True


def _s3_code(exc: BaseException | None) -> str | None:
    """The S3 error code behind ``exc`` (botocore's ClientError among its causes), or None."""
    while exc is not None:
        response = getattr(exc, "response", None)
        if isinstance(response, dict):
            return response.get("Error", {}).get("Code")
        exc = exc.__cause__ or exc.__context__
    return None


def _protocols(fs) -> tuple[str, ...]:
    proto = fs.protocol
    return (proto,) if isinstance(proto, str) else tuple(proto)


def _put(fs, local: bool, path: str, data: bytes, tmp: str) -> None:
    """``data`` at ``path`` in one step (a local file through ``tmp`` and a rename, no ``tmp`` left on failure;
    an object store's put is whole already)."""
    if not local:
        fs.pipe_file(path, data)
        return
    try:
        with open(tmp, "wb") as fh:
            fh.write(data)
    except OSError:
        _unlink_quietly(tmp)
        raise
    os.replace(tmp, path)


def _unlink_quietly(path: str) -> None:
    try:
        os.unlink(path)
    except FileNotFoundError:
        return


def no_space(exc: BaseException) -> bool:
    """Whether ``exc`` (or an error it was raised from) is a full disk or quota."""
    while exc is not None:
        if isinstance(exc, OSError) and exc.errno in (errno.ENOSPC, errno.EDQUOT):
            return True
        exc = exc.__cause__ or exc.__context__
    return False


def process_alive(holder: dict) -> bool:
    """Whether the process of this host named by a lock still runs."""
    try:
        proc = psutil.Process(int(holder["pid"]))
        return abs(proc.create_time() - float(holder["started"])) < 1.0 and proc.status() != psutil.STATUS_ZOMBIE
    except (psutil.NoSuchProcess, KeyError, ValueError, TypeError):
        return False


def busy_message(label: str, path: str, holder: dict) -> str:
    renewed = _number(holder, "renewed")
    lease = _number(holder, "lease_s")
    lease_text = ""
    if renewed is not None and lease is not None:
        lease_text = f", lease renewed {time.time() - renewed:.0f} s ago, expires in {renewed + lease - time.time():.0f} s"
    return (f"partition {label} is being written by another run ({describe(holder)}{lease_text}); wait for it "
            f"to finish; if that process is gone the lock is taken over once its lease expires "
            f"(${LEASE_ENV}, default {DEFAULT_LEASE_S:g} s), or delete {path} if you know no run holds it")


def describe(holder: dict) -> str:
    return (f"{holder.get('run', '?')}: host {holder.get('host')} pid {holder.get('run_pid', holder.get('pid'))} "
            f"since {holder.get('since')}")


def _encode(info: dict) -> bytes:
    return json.dumps({**info, "renewed": time.time()}).encode()


def _token(holder: dict | None) -> str | None:
    if holder is None:
        return None
    return str(holder.get("token") or UNREADABLE)


def _number(holder: dict, field: str) -> float | None:
    try:
        return float(holder[field])
    except (KeyError, TypeError, ValueError):
        return None


# ---- run leases ------------------------------------------------------------------------------------------------
class RunLease:
    """A run's (or a gc's) lease on the versions it reads and writes, for its whole life: ``<folder>/<id>.json``
    naming its holder (as a lock does), ``kind`` ("run" or "gc") and ``versions`` ([stage, key] pairs), renewed
    from a daemon thread like a lock and deleted at its end. ``mocapflow gc`` deletes no version a live lease
    holds; a lease is dead as a lock is stale (its process gone on this host, its lease run out, impossible
    fields)."""

    def __init__(self, fs, folder: str, local: bool, label: str, kind: str, versions: list[tuple[str, str]],
                 run_id: str | None = None, lease_s: float | None = None):
        self.fs, self.local = fs, local
        self.me = holder_info(label, lease_seconds() if lease_s is None else lease_s)
        self.me.update(kind=kind, run_id=run_id or self.me["token"][:12],
                       versions=[[str(stage), str(key)] for stage, key in versions])
        self.path = f"{folder.rstrip('/')}/{self.me['run_id']}.json"
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    @property
    def run_id(self) -> str:
        return str(self.me["run_id"])

    def start(self) -> None:
        self.fs.makedirs(self.path.rsplit("/", 1)[0], exist_ok=True)
        self._write()
        self._thread = threading.Thread(target=self._beat, name=f"run lease {self.run_id}", daemon=True)
        self._thread.start()

    def end(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=5.0)
        try:
            self.fs.rm_file(self.path)
        except FileNotFoundError:
            return

    def _write(self) -> None:
        _put(self.fs, self.local, self.path, _encode(self.me), f"{self.path}.tmp")

    def _beat(self) -> None:
        interval = float(self.me["lease_s"]) / HEARTBEATS_PER_LEASE
        while not self._stop.wait(interval):
            try:
                self._write()
            except OSError as exc:
                log.warning("run %s: could not renew its lease %s (%s); retrying in %.1f s", self.run_id, self.path,
                            exc, interval)


def read_run_leases(fs, folder: str) -> tuple[list[dict], list[str]]:
    """The live run leases in ``folder`` (each with its ``path``), and the paths of the dead ones."""
    try:
        paths = [p for p in fs.glob(f"{folder.rstrip('/')}/*.json")]
    except FileNotFoundError:
        return [], []
    live, dead = [], []
    for path in sorted(paths):
        try:
            info = json.loads(fs.cat_file(path))
        except FileNotFoundError:
            continue  # ended meanwhile
        except ValueError:
            info = {}
        if not isinstance(info, dict):
            info = {}
        (dead if lease_dead(fs, path, info) else live).append({**info, "path": path} if info else {"path": path})
    return live, [i["path"] for i in dead]


def lease_dead(fs, path: str, info: dict) -> bool:
    """Whether the run lease ``info`` (read from ``path``) is dead, by the rules of a stale lock."""
    if not info:
        try:
            age = time.time() - fs.modified(path).timestamp()
        except (FileNotFoundError, NotImplementedError):
            return True
        return age > UNREADABLE_GRACE_S
    if info.get("host") == hostname() and not process_alive(info):
        return True
    problem = impossible(info)
    if problem is not None:
        log.warning("run lease %s of %s is malformed (%s); treating it as dead", path, describe(info), problem)
        return True
    renewed = _number(info, "renewed")
    lease = _number(info, "lease_s") or lease_seconds()
    return renewed is None or time.time() - renewed > lease

"""A studio catalog run once per pytest run and copied into each test that reads it.

Several tests look at the same small run from different sides (the engine's cache, the report, the exports).
``shared_run`` runs the catalog the first time a test asks for it, under a lock that the pytest-xdist workers
of one pytest run share, and later tests of any worker copy the finished project into their own folder, so
that none of them changes what another reads. The folder lives under that run's own temporary root: a
later run (or another checkout) never sees it.
"""

from __future__ import annotations

import fcntl
import json
import shutil
from pathlib import Path
from typing import Callable

from conftest import last_json, mocapflow


def _run_root(request) -> Path:
    """A folder shared by the xdist workers of this pytest run only (the controller's test run id names it)."""
    factory = request.getfixturevalue("tmp_path_factory")
    worker = getattr(request.config, "workerinput", None)
    if worker is None:
        return factory.getbasetemp() / "shared-runs"
    return factory.getbasetemp().parent / f"shared-runs-{worker['testrunuid']}"


def shared_run(request, name: str, catalog: str | None, timeout: float = 1200,
               prepare: Callable[[Path], object] | None = None, args: tuple[str, ...] = ()) -> dict:
    """Run ``catalog`` (its text) once for the pytest run under the name ``name``; the JSON summary of that first
    `mocapflow run --json`. ``prepare(folder)`` writes what else the project holds (its data; its catalog.yaml
    too where ``catalog`` is None); ``args``: more options of that run (``--until STAGE``). Copy the project with
    ``copy_run``."""
    folder = _run_root(request) / name
    folder.parent.mkdir(parents=True, exist_ok=True)
    with open(folder.parent / f"{name}.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)  # the other workers wait here while the first one runs it
        summary = folder / "run.json"
        if not summary.exists():
            if folder.exists():
                shutil.rmtree(folder)  # a run that failed half-way in an earlier test: start again
            folder.mkdir()
            if prepare is not None:
                prepare(folder)
            if catalog is not None:
                (folder / "catalog.yaml").write_text(catalog)
            first = last_json(mocapflow("run", "--json", *args, cwd=folder, timeout=timeout))
            summary.write_text(json.dumps(first))
    return json.loads(summary.read_text())


def copy_run(request, name: str, to: Path) -> Path:
    """A private copy of the pytest run's run ``name`` (run it first with ``shared_run``) at ``to``."""
    shutil.copytree(_run_root(request) / name, to, ignore=shutil.ignore_patterns("run.json"))
    return to

"""A storage root or demo folder this process cannot write: one line saying so, and a cached run still reports."""

from __future__ import annotations

import os
import shutil
import subprocess
from pathlib import Path

import pytest

from conftest import mocapflow


@pytest.fixture
def read_only(tmp_path):
    """``read_only(folder)``: a read-only view of ``folder`` (a read-only bind mount where the tests run as root,
    whom a chmod does not stop; else the folder itself, chmodded), unmounted afterwards."""
    mounts = []

    def make(folder: Path) -> Path:
        if os.geteuid() != 0:
            for path in [folder, *folder.rglob("*")]:
                path.chmod(path.stat().st_mode & ~0o222)
            return folder
        if shutil.which("mount") is None:
            pytest.skip("running as root without `mount`: cannot make a read-only folder (chmod does not stop root)")
        view = tmp_path / f"ro-{folder.name}"
        view.mkdir()
        for args in (["--bind", str(folder), str(view)], ["-o", "remount,ro,bind", str(view)]):
            proc = subprocess.run(["mount", *args], capture_output=True, text=True)
            if proc.returncode != 0:
                if args[0] != "--bind":
                    subprocess.run(["umount", str(view)], check=False)
                pytest.skip(f"cannot make a read-only bind mount here (mount {' '.join(args)}: {proc.stderr.strip()})")
        mounts.append(view)
        return view

    yield make
    for view in mounts:
        subprocess.run(["umount", str(view)], check=False)


def test_a_cached_run_reports_from_a_read_only_store_and_a_run_with_work_is_refused_in_one_line(toy_project,
                                                                                                read_only):
    project = toy_project(sequences=("seqA",))
    mocapflow("run", "--workers", "1", cwd=project)
    ro = read_only(project / "storage")
    with pytest.raises(OSError):
        (ro / "probe").write_text("x")

    cached = mocapflow("run", "--set", f"storage.root={ro}", "--json", cwd=project)
    summary = cached.stdout.strip().splitlines()[-2]
    assert summary.startswith("0 executed, 6 cached, 0 failed, 0 skipped"), cached.stdout
    assert summary.endswith(f"no log (the storage root {ro} is read-only)"), summary
    assert cached.stderr == "", cached.stderr

    refused = mocapflow("run", "--set", f"storage.root={ro}", "--set", "stages.scaled.params.factor=5", cwd=project,
                        check=False)
    assert refused.returncode == 2 and refused.stdout == ""
    assert refused.stderr.strip().splitlines() == [
        f"error: the storage root {ro} is read-only (or not writable by this user) and 5 partition(s) are to be "
        "computed, e.g. scaled/seqA/cam0; make it writable, or pass --set storage.root=<a writable folder>"]
    assert sorted(p.name for p in ro.iterdir()) == ["diffed", "frames", "logs", "runs", "scaled", "summed"]


def test_a_demo_in_a_read_only_folder_is_refused_in_one_line(tmp_path, read_only):
    folder = tmp_path / "shelf"
    folder.mkdir()
    ro = read_only(folder)
    proc = mocapflow("demo", "--out", ro / "demo", cwd=tmp_path, check=False)
    assert proc.returncode == 2
    assert proc.stderr.strip().splitlines() == [
        f"error: --out {ro / 'demo'}: cannot write in {ro} (read-only, or not writable by this user); choose a "
        "writable --out folder"]
    assert list(ro.iterdir()) == []

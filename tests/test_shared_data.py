"""The needs_shared marker: a test reading ../shared/data skips where it is missing, fails in CI
(MOCAPFLOW_REQUIRE_SHARED=1), and runs where it is there. Each case runs pytest on a one-test file."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from shared_data import C3D_FILES, CALIBRATION_FILES, CMU_CLIPS

PROBE = """\
import pytest

@pytest.mark.needs_shared
def test_reads_the_clips():
    pass
"""


def run_probe(tmp_path: Path, shared: Path, require: bool) -> subprocess.CompletedProcess:
    (tmp_path / "test_probe.py").write_text(PROBE)
    env = dict(os.environ, MOCAPFLOW_SHARED_DATA=str(shared))
    env.pop("MOCAPFLOW_REQUIRE_SHARED", None)
    if require:
        env["MOCAPFLOW_REQUIRE_SHARED"] = "1"
    env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(Path(__file__).parent), env.get("PYTHONPATH")]))
    return subprocess.run([sys.executable, "-m", "pytest", "-q", "-rsf", "-p", "shared_data", "-p", "no:cacheprovider",
                           "--rootdir", str(tmp_path), "test_probe.py"],
                          cwd=tmp_path, env=env, capture_output=True, text=True, timeout=120)


@pytest.mark.parametrize("require", [False, True], ids=["plain clone", "CI"])
def test_missing_shared_data_skips_naming_what_and_where_unless_ci_requires_it(tmp_path, require):
    proc = run_probe(tmp_path, tmp_path / "elsewhere", require)
    expected = str(tmp_path / "elsewhere" / "motions")
    if require:
        assert proc.returncode == 1 and "1 error" in proc.stdout, proc.stdout + proc.stderr  # at setup
        assert "MOCAPFLOW_REQUIRE_SHARED=1" in proc.stdout
    else:
        assert proc.returncode == 0 and "1 skipped" in proc.stdout, proc.stdout + proc.stderr
    assert "CMU BVH clips are missing" in proc.stdout and expected in proc.stdout.replace("\n", "")


def test_a_missing_clip_is_named_and_present_data_runs_the_test(tmp_path):
    motions = tmp_path / "data" / "motions"
    motions.mkdir(parents=True)
    for name in CMU_CLIPS[1:]:
        (motions / name).write_text("")
    proc = run_probe(tmp_path, tmp_path / "data", require=False)
    assert "1 skipped" in proc.stdout and CMU_CLIPS[0] in proc.stdout, proc.stdout + proc.stderr
    (motions / CMU_CLIPS[0]).write_text("")
    proc = run_probe(tmp_path, tmp_path / "data", require=False)  # the clips are there, the C3D files not yet
    assert "1 skipped" in proc.stdout and C3D_FILES[0] in proc.stdout, proc.stdout + proc.stderr
    (tmp_path / "data" / "c3d").mkdir()
    for name in C3D_FILES:
        (tmp_path / "data" / "c3d" / name).write_text("")
    proc = run_probe(tmp_path, tmp_path / "data", require=False)  # the C3D files are there, the calibration not yet
    assert "1 skipped" in proc.stdout and CALIBRATION_FILES[0] in proc.stdout, proc.stdout + proc.stderr
    (tmp_path / "data" / "calibration").mkdir()
    for name in CALIBRATION_FILES:
        (tmp_path / "data" / "calibration" / name).write_text("")
    for require in (False, True):
        proc = run_probe(tmp_path, tmp_path / "data", require)
        assert proc.returncode == 0 and "1 passed" in proc.stdout, proc.stdout + proc.stderr

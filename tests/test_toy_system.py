"""A fourth capture system added from outside the engine (tests/plugins/toy_system, docs/adding-a-system.md): found
through the ``mocapflow.systems`` entry point group of an installed distribution, it runs, evaluates and exports
through the `mocapflow` command, with no line of pipeline/ naming it."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np

PLUGINS = Path(__file__).parent / "plugins"
CATALOG = """\
storage: {{root: storage/}}
datasets:
  walks:
    kind: toy_walk
    sequences:
      slow: {{frames: 40, speed: 0.5, noise_mm: {noise}, seed: 1}}
      fast: {{frames: 30, speed: 2.0, noise_mm: {noise}, seed: 2}}
stages:
  walk: {{task: toy_record, dataset: walks}}
  smooth: {{task: toy_smooth, inputs: [walk], params: {{window: 5}}}}
"""


def installed(tmp_path: Path) -> dict:
    """The environment of a process where the toy system is an installed distribution: its module on the path and
    a dist-info declaring its entry point, as `pip install` would leave them."""
    site = tmp_path / "site"
    dist = site / "toy_system-1.0.dist-info"
    dist.mkdir(parents=True)
    (dist / "METADATA").write_text("Metadata-Version: 2.1\nName: toy-system\nVersion: 1.0\n")
    (dist / "entry_points.txt").write_text("[mocapflow.systems]\ntoy = toy_system:SYSTEM\n")
    paths = [str(site), str(PLUGINS), os.environ.get("PYTHONPATH", "")]
    return {**os.environ, "PYTHONPATH": os.pathsep.join(p for p in paths if p)}


def mocapflow(env: dict, cwd: Path, *args: str) -> str:
    proc = subprocess.run([sys.executable, "-m", "mocapflow.cli.commands", *args], cwd=cwd, env=env,
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-3000:]
    return proc.stdout


def test_a_fourth_system_runs_evaluates_and_exports_through_the_cli(tmp_path):
    env = installed(tmp_path)
    (tmp_path / "catalog.yaml").write_text(CATALOG.format(noise=5))
    mocapflow(env, tmp_path, "run", "--workers", "1")
    figures = json.loads(mocapflow(env, tmp_path, "evaluate", "--json", "--workers", "1").splitlines()[-1])
    assert figures["sequences"] == 2
    # noise of 5 mm per axis (8.7 mm per point) averaged over 5 frames: about 8.7 / sqrt(5) = 3.9 mm, the walk's
    # straight line passing through the average unchanged
    assert 2.5 < figures["toy_rmse_mm"] < 5.5
    out = mocapflow(env, tmp_path, "export", "--format", "csv", "--out", "csv", "--workers", "1")
    assert sorted(line.split()[-1] for line in out.splitlines()) == [str(Path("csv") / f"{s}.csv")
                                                                      for s in ("fast", "slow")]
    rows = np.loadtxt(tmp_path / "csv" / "slow.csv", delimiter=",", skiprows=1)
    assert rows.shape == (40, 4)
    np.testing.assert_allclose(rows[10:30, 1], np.arange(10, 30) / 30.0 * 0.5, atol=0.01)  # x follows the walk
    np.testing.assert_allclose(rows[:, 3], 1.0, atol=0.01)


def test_a_noisier_walk_scores_worse(tmp_path):
    env = installed(tmp_path)
    (tmp_path / "catalog.yaml").write_text(CATALOG.format(noise=20))
    figures = json.loads(mocapflow(env, tmp_path, "evaluate", "--json", "--workers", "1").splitlines()[-1])
    assert 10.0 < figures["toy_rmse_mm"] < 22.0  # four times the noise, four times the error


def test_without_its_distribution_the_system_is_unknown(tmp_path):
    (tmp_path / "catalog.yaml").write_text(CATALOG.format(noise=5))
    proc = subprocess.run([sys.executable, "-m", "mocapflow.cli.commands", "run", "--dry-run"], cwd=tmp_path,
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode != 0
    assert "unknown dataset kind 'toy_walk'" in proc.stderr



def test_its_command_joins_the_command_line(tmp_path):
    env = installed(tmp_path)
    listed = mocapflow(env, tmp_path, "--help")
    assert "toy-walk" in listed and "synth" in listed  # the toy's command and DeepMoCap's, beside the engine's
    rows = np.loadtxt(mocapflow(env, tmp_path, "toy-walk", "--frames", "4", "--speed", "3").splitlines()[1:],
                      delimiter=",")
    np.testing.assert_allclose(rows, [[0, 0.0], [1, 0.1], [2, 0.2], [3, 0.3]], atol=1e-6)
    plain = subprocess.run([sys.executable, "-m", "mocapflow.cli.commands", "toy-walk"], cwd=tmp_path,
                           capture_output=True, text=True, timeout=300)
    assert plain.returncode != 0 and "No such command 'toy-walk'" in plain.stderr  # not installed: not there

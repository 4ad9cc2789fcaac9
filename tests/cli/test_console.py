"""What the console says: the log a cached run names exists, grids for marker catalogs, catalog lines, options
validated before folders are made, the synth hint, warp's CUDA warning, the 3D view's marker colours, export
refusing to overwrite, a sequence's own layout file."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys

import numpy as np
import pytest

from conftest import mocapflow
from mocapflow.formats.c3d import write_points
from mocapflow.pipeline.runlog import run_log
from mocapflow.pipeline.storage import Store
from mocapflow.presentation.viewer import VIEWER_JS


def test_a_run_that_logs_nothing_still_leaves_the_log_it_names(tmp_path):
    with run_log(Store(str(tmp_path / "storage")), "demo") as path:
        pass
    text = (tmp_path / "storage" / "logs" / path.rsplit("/", 1)[-1]).read_text()
    assert text.startswith("mocapflow demo (") and "mocapflow demo finished" in text


def test_status_and_dry_run_show_a_column_per_sequence_of_a_marker_catalog(tmp_path):
    (tmp_path / "takes").mkdir()
    for name in ("walk", "jump"):
        xyz = np.random.default_rng(0).uniform(-500, 500, (20, 3, 3))
        write_points(tmp_path / "takes" / f"{name}.c3d", xyz, ["A", "B", "C"], 100.0, -1.0, np.zeros((20, 3)))
    (tmp_path / "catalog.yaml").write_text(
        "data_roots: [.]\nstorage: {root: storage/}\ndatasets:\n  lab: {kind: markers, path: takes}\n"
        "stages:\n  markers: {task: ingest_markers, dataset: lab}\n")
    status = mocapflow("status", cwd=tmp_path).stdout.splitlines()
    assert status[0].split() == ["stage", "jump", "walk"] and status[1].split() == ["markers", "missing", "missing"]
    dry = mocapflow("run", "--dry-run", cwd=tmp_path).stdout.splitlines()
    assert dry[0].split() == ["stage", "jump", "walk"] and dry[1].split() == ["markers", "run", "run"]


STUDIO = """\
data_roots: [.]
storage: {root: storage/}
datasets:
  recordings:
    kind: studio
    defaults:
      frames: 30
      fps: FPS
    sequences:
      walk: {motion: jumping_jack}
      squat: SQUAT
      curl: {motion: elbow_flexion}
stages:
  frames: {task: ingest, dataset: recordings}
"""


@pytest.mark.parametrize("fps, squat, message", [
    ("30.0", "{seed: 3}", "catalog.yaml (line 11): datasets.recordings.sequences.squat: no 'motion'"),
    ("fast", "{motion: classic_squat}",
     "catalog.yaml (line 8): datasets.recordings.defaults.fps: expected float, got str 'fast'"),
])
def test_catalog_errors_name_the_line_and_key_they_come_from(tmp_path, fps, squat, message):
    (tmp_path / "catalog.yaml").write_text(STUDIO.replace("FPS", fps).replace("SQUAT", squat))
    proc = mocapflow("status", cwd=tmp_path, check=False)
    assert proc.returncode == 2 and proc.stderr.startswith(f"error: {message}"), proc.stderr


def test_demo_options_are_checked_before_any_folder_is_made(tmp_path):
    proc = mocapflow("demo", "--frames", "-5", "--out", "dneg", cwd=tmp_path, check=False)
    assert proc.returncode == 2 and "--frames -5 is too short" in proc.stderr
    assert not (tmp_path / "dneg").exists()


def test_synth_names_its_skeleton_option_for_an_amc_take(tmp_path):
    (tmp_path / "take.amc").write_text(":FULLY-SPECIFIED\n:DEGREES\n1\nroot 0 0 0 0 0 0\n")
    proc = mocapflow("synth", "--out", "out", "--motion", "take.amc", cwd=tmp_path, check=False)
    assert proc.returncode == 2 and "needs its ASF skeleton: pass --skeleton subject.asf" in proc.stderr, proc.stderr
    assert not (tmp_path / "out").exists()


def test_the_body_model_loads_without_warps_cuda_driver_warning():
    code = ("from mocapflow.tasks.shared.mesh_body import anny_model\n"
            "import sys; anny_model(); sys.stderr.write('loaded\\n')")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0 and proc.stderr.strip().endswith("loaded"), proc.stderr
    assert "CUDA driver" not in proc.stderr and "CUDA driver" not in proc.stdout


@pytest.mark.parametrize("count", [5, 20, 26, 104])
def test_every_marker_of_a_take_gets_its_own_colour(count):
    if shutil.which("node") is None:
        pytest.skip("node is not installed: the 3D view's colour function is not run")
    palette = [f"#{i:02x}0000" for i in range(20)]
    script = (VIEWER_JS + f"\nvar p = {json.dumps(palette)}, out = [];\n"
              f"for (var m = 0; m < {count}; m++) out.push(markerColour(m, {count}, p));\n"
              "console.log(JSON.stringify(out));\n")
    colours = json.loads(subprocess.run(["node", "-e", script], capture_output=True, text=True, check=True).stdout)
    assert len(colours) == count and len(set(colours)) == count
    if count <= 20:
        assert colours == palette[:count]  # the categorical palette while it has a colour for each


def test_export_refuses_an_existing_file_unless_forced(tmp_path):
    from test_toy_system import CATALOG, installed

    env = installed(tmp_path)
    (tmp_path / "catalog.yaml").write_text(CATALOG.format(noise=5))

    def export(*extra):
        return subprocess.run([sys.executable, "-m", "mocapflow.cli.commands", "export", "--format", "csv", "--out",
                               "csv", "--workers", "1", "--threads", *extra], cwd=tmp_path, env=env,
                              capture_output=True, text=True, timeout=300)

    assert export().returncode == 0
    (tmp_path / "csv" / "fast.csv").write_text("mine\n")
    refused = export()
    assert refused.returncode == 2 and (tmp_path / "csv" / "fast.csv").read_text() == "mine\n"
    assert refused.stderr.strip() == "error: csv/fast.csv exists (and 1 more of the files to write); pass --force to " \
                                     "overwrite, or choose another --out", refused.stderr
    assert export("--force").returncode == 0 and (tmp_path / "csv" / "fast.csv").read_text().startswith("frame,x")
    assert sorted(p.name for p in (tmp_path / "csv").iterdir()) == ["fast.csv", "slow.csv"]  # no staging left


def test_a_studio_sequence_reads_its_own_layout_file(tmp_path):
    (tmp_path / "wide.yaml").write_text("ring: {count: 4, radius: 3.5, height: 1.2}\n")
    catalog = (STUDIO.replace("FPS", "30.0").replace("SQUAT", "{motion: classic_squat, views: 4, layout: LAYOUT}"))
    (tmp_path / "catalog.yaml").write_text(catalog.replace("LAYOUT", "wide.yaml"))
    status = mocapflow("status", cwd=tmp_path).stdout.splitlines()[0].split()
    assert [c for c in status if c.startswith("squat/")] == [f"squat/kinect{i}" for i in range(4)]
    (tmp_path / "catalog.yaml").write_text(catalog.replace("LAYOUT", "{ring: {count: 4}}"))
    proc = mocapflow("status", cwd=tmp_path, check=False)
    assert proc.returncode == 2 and "datasets.recordings.sequences.squat.layout: expected a camera layout file" \
        in proc.stderr, proc.stderr

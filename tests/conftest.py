"""Shared test helpers: tiny raw recordings, catalogs and `mocapflow` subprocesses."""

from __future__ import annotations

import json
import os
import subprocess
import time
import sys
from pathlib import Path

import numpy as np
import pytest

from mocapflow.schemas.raw import make_raw_sequence
from shared_data import SHARED, pytest_configure, pytest_runtest_setup  # noqa: F401  (the needs_shared marker)

ROOT = Path(__file__).resolve().parents[1]


def pytest_sessionstart(session):
    """Under pytest-xdist, build the body model's caches (Anny's model data, warp's skinning kernel and the marker
    takes' sight-line kernel) once in the controller before the workers start, so that they never write them at
    the same time on a fresh machine."""
    if getattr(session.config.option, "numprocesses", None) and not hasattr(session.config, "workerinput"):
        from mocapflow.tasks.shared.mesh_body import Phenotype, mesh_body, pose_mesh
        from mocapflow.tasks.uuo.sight_lines import cameras_seeing

        body = mesh_body(Phenotype())
        posed = pose_mesh(body, np.tile(np.eye(3), (1, len(body.bone_names), 1, 1)), np.zeros((1, 3)))
        cameras_seeing(posed.vertices, body.faces, posed.vertices[:, :1], np.array([[0.0, -3.0, 1.0]]))
PLUGINS = ROOT / "tests" / "plugins"


def env_with_plugins() -> dict:
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(PLUGINS), env.get("PYTHONPATH")]))
    env["PYTHONUNBUFFERED"] = "1"
    return env


def mocapflow(*args, cwd, check=True, timeout=300) -> subprocess.CompletedProcess:
    """Run the real CLI in a subprocess; returns the CompletedProcess (text)."""
    proc = subprocess.run([sys.executable, "-m", "mocapflow.cli.commands", *map(str, args)], cwd=cwd,
                          env=env_with_plugins(), capture_output=True, text=True, timeout=timeout)
    if check and proc.returncode != 0:
        raise AssertionError(f"mocapflow {' '.join(map(str, args))} exited {proc.returncode}\n"
                             f"stdout:\n{proc.stdout}\nstderr:\n{proc.stderr}")
    return proc


def wait_for(predicate, timeout=120.0, what="condition"):
    """Poll ``predicate`` until it holds (a file a process writes may be half-written meanwhile: OSError and
    ValueError count as not yet); AssertionError naming ``what`` after ``timeout`` seconds."""
    deadline = time.time() + timeout
    while time.time() < deadline:
        try:
            if predicate():
                return
        except (OSError, ValueError):
            pass
        time.sleep(0.05)
    raise AssertionError(f"{what} not met within {timeout:.0f} s")


def last_json(proc: subprocess.CompletedProcess) -> dict:
    return json.loads(proc.stdout.strip().splitlines()[-1])


def write_raw_zarr(path: Path, *, views=("cam0", "cam1"), frames=20, seed=0, size=(12, 16)) -> None:
    rng = np.random.default_rng(seed)
    h, w = size
    cams = {v: dict(fx=100.0, fy=100.0, cx=w / 2, cy=h / 2, dist=[0.0] * 5, cam_to_world=np.eye(4),
                    width=w, height=h) for v in views}
    depth = rng.integers(500, 4000, (len(views), frames, h, w)).astype(np.uint16)
    make_raw_sequence(depth, depth // 3, cams, 30.0, 0).to_zarr(path, zarr_format=3, consolidated=False, mode="w")


TOY_CATALOG = """\
plugins: [toytasks]
storage: {{root: {root}, region_frames: {region}}}
datasets:
  rec: {{kind: zarr, path: data}}
stages:
  frames: {{task: ingest}}
  scaled: {{task: scale, inputs: [frames], params: {{factor: 3, sleep: {sleep}}}}}
  diffed: {{task: diff, inputs: [scaled]}}
  summed: {{task: total, inputs: [scaled]}}
"""


def make_toy_project(folder: Path, *, root="storage/", region=4, sleep=0.0, frames=20,
                     sequences=("seqA", "seqB")) -> Path:
    """Two tiny raw sequences (2 views, 20 frames) and a catalog of toy stages in ``folder``."""
    (folder / "data").mkdir(exist_ok=True)
    for i, name in enumerate(sequences):
        write_raw_zarr(folder / "data" / f"{name}.zarr", frames=frames, seed=i)
    (folder / "catalog.yaml").write_text(TOY_CATALOG.format(root=root, region=region, sleep=sleep))
    return folder


@pytest.fixture
def toy_project(tmp_path):
    """A folder with two tiny raw sequences (2 views, 20 frames) and a catalog of toy stages (make_toy_project)."""

    def make(**options) -> Path:
        return make_toy_project(tmp_path, **options)

    return make


@pytest.fixture
def toy_run(request, tmp_path):
    """A toy project (``toy_project(**options)``, storage under the project) after one `mocapflow run --json`, up to
    the stage ``until`` where given: that run is made once per pytest run for each set of options and shared by its
    workers (shared_runs.shared_run); each test gets its own copy. Returns (folder, the first run's JSON summary)."""
    from shared_runs import copy_run, shared_run

    def make(until: str | None = None, **options) -> tuple[Path, dict]:
        name = "toy" + "".join(f"-{k}={v}" for k, v in sorted(options.items())).replace("'", "").replace(" ", "")
        name += f"-until-{until}" if until else ""
        first = shared_run(request, name, None, prepare=lambda folder: make_toy_project(folder, **options),
                           args=("--until", until) if until else ())
        return copy_run(request, name, tmp_path / "toy"), first

    return make


def read_artifacts(root: Path) -> dict:
    """partition id -> {variable: ndarray} for every complete version under a storage root."""
    import xarray as xr

    out = {}
    for lineage_path in sorted(root.glob("*/*/lineage.json")):
        version = lineage_path.parent
        if not (version / "_COMPLETE").exists():
            continue
        lineage = json.loads(lineage_path.read_text())
        ds = xr.open_zarr(version / "data.zarr", consolidated=False, chunks=None)
        out[(lineage["partition"], lineage["key"])] = {k: ds[k].values for k in ds.data_vars}
    return out


def assert_same_artifacts(a: dict, b: dict) -> None:
    assert a.keys() == b.keys()
    for key in a:
        for var in a[key]:
            np.testing.assert_array_equal(a[key][var], b[key][var], err_msg=f"{key} {var}")


# ---- an analytic scene for the flow stages ---------------------------------------------------
PLANE_W, PLANE_H, PLANE_F = 512, 424, 365.0  # the Kinect-v2 depth sensor's geometry


def plane_texture(x, y):
    """IR counts of a textured surface at world (x, y) metres."""
    return 3000 + 1200 * np.sin(x * 31) * np.sin(y * 23) + 800 * np.sin((x + 2 * y) * 13)


def plane_sequence(motions, z0=2.0, hole=None):
    """Frames of a fronto-parallel textured plane; frame k is moved by the sum of motions[:k] (metres)."""
    ys, xs = np.mgrid[0:PLANE_H, 0:PLANE_W].astype(np.float64)
    rays = np.stack([(xs - PLANE_W / 2) / PLANE_F, (ys - PLANE_H / 2) / PLANE_F], axis=-1)
    offset = np.zeros(3)
    depth, ir = [], []
    for k in range(len(motions) + 1):
        if k:
            offset = offset + np.asarray(motions[k - 1])
        z = z0 + offset[2]
        px, py = rays[..., 0] * z - offset[0], rays[..., 1] * z - offset[1]  # surface coordinates
        d = np.full((PLANE_H, PLANE_W), np.rint(z * 1000))
        i = plane_texture(px, py)
        if hole is not None:  # a reflector fixed on the surface: no depth, saturated IR
            inside = (np.abs(px - hole[0]) < 0.07) & (np.abs(py - hole[1]) < 0.07)
            d[inside], i[inside] = 0, 65000
        depth.append(d)
        ir.append(i)
    cams = {"cam": dict(fx=PLANE_F, fy=PLANE_F, cx=PLANE_W / 2, cy=PLANE_H / 2, dist=[0.0] * 5, cam_to_world=np.eye(4),
                    width=PLANE_W, height=PLANE_H)}
    return make_raw_sequence(np.stack(depth)[None], np.stack(ir)[None], cams, 30.0, 0)

"""Content-addressed caching: no-op reruns, exact downstream recomputation, swap and swap back, gc."""

from __future__ import annotations

import json

import numpy as np
import xarray as xr

from conftest import last_json, mocapflow

ALL_TOY = {f"{stage}/{seq}{view}" for seq in ("seqA", "seqB")
           for stage, views in (("frames", [""]), ("scaled", ["/cam0", "/cam1"]), ("diffed", ["/cam0", "/cam1"]),
                                ("summed", [""]))
           for view in views}


def run(project, *extra):
    return last_json(mocapflow("run", "--json", *extra, cwd=project))


def test_rerun_with_nothing_changed_executes_nothing(toy_run):
    project, first = toy_run()  # the first run of the toy project, made once for the tests that start from it
    assert set(first["executed"]) == ALL_TOY and first["failed"] == []
    second = run(project)
    assert second["executed"] == [] and set(second["cached"]) == ALL_TOY


def test_param_change_recomputes_stage_and_downstream_only_and_swap_back_is_free(toy_run):
    project, _ = toy_run()
    changed = run(project, "--set", "stages.scaled.params.factor=5")
    assert set(changed["executed"]) == {p for p in ALL_TOY if not p.startswith("frames/")}
    assert set(changed["cached"]) == {"frames/seqA", "frames/seqB"}
    assert run(project)["executed"] == []  # back to factor 3: every version is still stored
    assert run(project, "--set", "stages.scaled.params.factor=5")["executed"] == []


def test_swapping_implementation_recomputes_downstream_and_swapping_back_recomputes_nothing(toy_run):
    project, _ = toy_run()
    swapped = run(project, "--set", "stages.scaled.task=scale_plus")
    assert set(swapped["executed"]) == {p for p in ALL_TOY if not p.startswith("frames/")}
    assert run(project)["executed"] == []
    assert run(project, "--set", "stages.scaled.task=scale_plus")["executed"] == []


def test_region_size_is_layout_not_content(toy_run):
    project, _ = toy_run()
    (project / "catalog.yaml").write_text((project / "catalog.yaml").read_text().replace(
        "diffed: {task: diff, inputs: [scaled]}", "diffed: {task: diff, inputs: [scaled], region_frames: 8}"))
    # region size is layout, not content: same keys, nothing to run
    assert run(project)["executed"] == []


def test_outputs_have_the_right_values_and_lineage(toy_run):
    project, _ = toy_run()
    raw = xr.open_zarr(project / "data" / "seqA.zarr", consolidated=False)
    versions = {json.loads(p.read_text())["partition"]: p.parent for p in (project / "storage").glob("*/*/lineage.json")}
    diffed = xr.open_zarr(versions["diffed/seqA/cam1"] / "data.zarr", consolidated=False)
    scaled = raw.depth.sel(view="cam1").values.astype(np.float32) * 3
    expected = scaled - np.concatenate([np.zeros_like(scaled[:1]), scaled[:-1]])  # halo crosses region borders
    np.testing.assert_array_equal(diffed.value.sel(view="cam1").values, expected)
    summed = xr.open_zarr(versions["summed/seqA"] / "data.zarr", consolidated=False)
    np.testing.assert_array_equal(summed.total.values, raw.depth.values.astype(np.float32).sum(0) * 3)
    lineage = diffed.attrs["mocapflow_lineage"]
    assert lineage["components"]["task"] == "diff" and lineage["components"]["code_version"] == "1"
    assert set(lineage["components"]["upstream"]["scaled"]["keys"]) == {"cam1"}
    assert {"started", "finished", "host", "compute_seconds"} <= set(lineage)
    assert diffed.value.encoding["chunks"] == (1, 4, 12, 16)  # chunked per frame region


def test_explain_names_the_changed_component(toy_run):
    project, _ = toy_run()
    out = mocapflow("explain", "scaled", "seqA", "cam0", "--set", "stages.scaled.params.factor=7", cwd=project).stdout
    assert "params.factor: 3.0 -> 7.0" in out
    out = mocapflow("explain", "diffed", "seqA", "cam0", "--set", "stages.scaled.params.factor=7", cwd=project).stdout
    assert "upstream.scaled.keys.cam0" in out and "mocapflow explain scaled seqA cam0" in out
    out = mocapflow("explain", "scaled", "seqA", "cam0", cwd=project).stdout
    assert "is fresh" in out


def test_status_reports_fresh_stale_and_missing(toy_project):
    project = toy_project()
    assert "12 missing" in mocapflow("status", cwd=project).stdout
    run(project, "--until", "scaled")
    out = mocapflow("status", "--set", "stages.scaled.params.factor=4", cwd=project).stdout
    assert "2 fresh" in out and "4 stale" in out and "6 missing" in out  # frames x2 fresh, scaled x4 stale


def test_gc_deletes_only_unreferenced_versions(toy_run):
    project, _ = toy_run()
    run(project, "--set", "stages.scaled.params.factor=5")
    out = mocapflow("gc", cwd=project).stdout
    assert "10 unreferenced version(s) deleted" in out
    assert run(project)["executed"] == []
    assert len(run(project, "--set", "stages.scaled.params.factor=5")["executed"]) == 10


def test_dry_run_prints_the_plan_and_writes_nothing(toy_project):
    project = toy_project()
    proc = mocapflow("run", "--dry-run", "--until", "scaled", cwd=project)
    assert proc.stdout.splitlines()[0].split() == ["stage", "seqA/cam0", "seqA/cam1", "seqB/cam0", "seqB/cam1"]
    assert "6 to run, 0 cached" in proc.stdout
    assert not (project / "storage").exists()


def test_only_and_sequences_select_partitions(toy_project):
    project = toy_project()
    first = run(project, "--until", "scaled", "--sequences", "seqB")
    assert set(first["executed"]) == {"frames/seqB", "scaled/seqB/cam0", "scaled/seqB/cam1"}
    only = run(project, "--only", "summed", "--sequences", "seqB")
    assert only["executed"] == ["summed/seqB"]
    proc = mocapflow("run", "--only", "summed", cwd=project, check=False)
    assert proc.returncode == 2 and "inputs are not computed yet: scaled/seqA/cam0" in proc.stderr
    assert "run `mocapflow run --until summed` instead" in proc.stderr

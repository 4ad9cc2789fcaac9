"""The command line's rough edges: every bad input is one clear line on stderr (exit 2), never a traceback;
explain and run account for every partition."""

from __future__ import annotations

import pytest
from click.testing import CliRunner

from conftest import PLUGINS, mocapflow
from mocapflow.cli import commands as cli
from mocapflow.pipeline.catalog import load_catalog
from mocapflow.pipeline.plan import build_plan
from mocapflow.pipeline.storage import Store


def one_line_error(proc) -> str:
    assert proc.returncode == 2, proc.stderr
    assert "Traceback" not in proc.stderr
    lines = [line for line in proc.stderr.splitlines() if line.strip()]
    assert len(lines) == 1, proc.stderr
    assert lines[0].startswith("error: ")
    return lines[0]


@pytest.mark.parametrize("args,message", [
    (["run", "--set", "storage.root=foo://x"],
     "error: catalog.yaml (--set): storage.root: cannot store artifacts at 'foo://x': Protocol not known: foo; use a "
     "folder or the URL of an installed fsspec filesystem (e.g. s3:// with s3fs)"),
    (["run", "--scheduler", "notanaddress"],
     "error: --scheduler 'notanaddress' is not a Dask scheduler address (missing port number in address "
     "'notanaddress'); pass the address `dask scheduler` prints, e.g. tcp://10.0.0.5:8786"),
    (["run", "--sequences", "zz*"],
     "error: --sequences 'zz*' matches none of the catalog's sequences ['seqA', 'seqB']; give a glob matching their "
     "ids, e.g. 'seqA*'"),
    (["status", "--sequences", "seqC"],
     "error: --sequences 'seqC' matches none of the catalog's sequences ['seqA', 'seqB']"),
    (["explain", "scaledd", "seqA", "cam0"],
     "error: explain: no stage 'scaledd' (did you mean 'scaled'?); stages: ['frames', 'scaled', 'diffed', 'summed']"),
    (["explain", "scaled", "seqZ", "cam0"], "error: explain: no sequence 'seqZ' (did you mean 'seq"),
    (["explain", "scaled", "seqA"],
     "error: explain: stage 'scaled' runs per view; add the VIEW argument, one of ['cam0', 'cam1']"),
    (["explain", "scaled", "seqA", "cam7"],
     "error: explain: sequence 'seqA' has no view 'cam7' (did you mean 'cam1'?); its views: ['cam0', 'cam1']"),
    (["explain", "summed", "seqA", "cam0"],
     "error: explain: stage 'summed' runs per sequence; drop the VIEW argument 'cam0'"),
])
def test_bad_command_lines_are_one_clear_line(toy_project, args, message):
    project = toy_project()
    line = one_line_error(mocapflow(*args, cwd=project, check=False))
    assert line.startswith(message)
    assert not (project / "storage").exists()


def test_a_storage_root_that_is_a_file_is_refused_at_load(toy_project):
    project = toy_project()
    (project / "afile").write_text("not a folder")
    line = one_line_error(mocapflow("run", "--set", "storage.root=afile/sub", cwd=project, check=False))
    assert line == (f"error: catalog.yaml (--set): storage.root: 'afile/sub' resolves to {project / 'afile' / 'sub'}, "
                    f"but {project / 'afile'} is a file; point storage.root at a folder")


def test_an_empty_weights_file_is_refused_naming_it(toy_project):
    project = toy_project()
    (project / "catalog.yaml").write_text((project / "catalog.yaml").read_text().replace(
        "task: scale, inputs: [frames], params: {factor: 3, sleep: 0.0}",
        "task: weighted, inputs: [frames], params: {weights: gain.pt}"))
    (project / "gain.pt").write_bytes(b"")
    line = one_line_error(mocapflow("run", cwd=project, check=False))
    assert line == (f"error: stages.scaled.params.weights: weights file {project / 'gain.pt'} is empty; train it again "
                    "(`mocapflow train`) or point the parameter at a complete weights file")


def test_zero_workers_is_a_usage_error(toy_project):
    proc = mocapflow("run", "--workers", "0", cwd=toy_project(), check=False)
    assert proc.returncode == 2 and "Traceback" not in proc.stderr
    assert "Invalid value for '--workers': 0 is not in the range x>=1." in proc.stderr


def test_explain_tells_a_partial_partition_from_one_never_computed(toy_project, monkeypatch):
    monkeypatch.syspath_prepend(str(PLUGINS))
    project = toy_project()
    catalog = load_catalog(project / "catalog.yaml")
    key = build_plan(catalog).items["scaled/seqA/cam0"].key
    never = mocapflow("explain", "scaled", "seqA", "cam0", cwd=project).stdout
    assert never.strip() == f"scaled/seqA/cam0 was never computed (key {key}); it would run"
    mocapflow("run", "--until", "scaled", cwd=project)
    version = project / "storage" / "scaled" / key
    (version / "_COMPLETE").unlink()  # as a run killed after its regions, before it committed the version
    for marker in sorted((version / "_regions").iterdir())[2:]:
        marker.unlink()
    assert Store(catalog.root).regions_done("scaled", key) == 2
    partial = mocapflow("explain", "scaled", "seqA", "cam0", cwd=project).stdout
    assert partial.strip() == (f"scaled/seqA/cam0 is partial: 2 region(s) of key {key} are written, the rest are not; "
                               "a run resumes it at the first missing region")


class _PlannedBeforeAnotherRunFinished(Store):
    """The store as a run saw it when it planned: nothing complete yet (another run completed it since)."""

    def is_complete(self, stage: str, key: str) -> bool:
        return False


def test_the_run_summary_counts_partitions_a_worker_found_complete(toy_project, monkeypatch):
    monkeypatch.syspath_prepend(str(PLUGINS))
    project = toy_project()
    mocapflow("run", cwd=project)  # the other run: every partition complete
    monkeypatch.chdir(project)
    monkeypatch.setattr(cli, "Store", _PlannedBeforeAnotherRunFinished)
    result = CliRunner().invoke(cli.main, ["run", "--threads", "--no-progress"])
    assert result.exit_code == 0, result.output
    assert result.output.splitlines()[-1].startswith("0 executed, 12 cached, 0 failed, 0 skipped in ")


def test_run_and_evaluate_print_the_root_failure_before_the_partitions_it_skipped(toy_project):
    project = toy_project()
    (project / "catalog.yaml").write_text((project / "catalog.yaml").read_text().replace(
        "task: scale,", "task: boom,").replace("params: {factor: 3, sleep: 0.0}", "params: {bad_view: cam1}"))
    going = mocapflow("run", "--keep-going", "--threads", cwd=project, check=False)
    assert going.returncode == 1
    lines = [line for line in going.stderr.splitlines() if line.startswith(("FAILED", "SKIPPED", "..."))]
    assert sorted(lines[:2]) == ["FAILED scaled/seqA/cam1: RuntimeError: boom on cam1",
                                 "FAILED scaled/seqB/cam1: RuntimeError: boom on cam1"]  # both root failures first
    assert all(line.startswith("SKIPPED") and ": upstream failed: scaled/seq" in line for line in lines[2:5])
    assert lines[5:] == ["... and 1 more skipped partition, 4 in all, none of them failed on its own"]
    proc = mocapflow("evaluate", "--threads", cwd=project, check=False)  # stops at the first failure
    assert proc.returncode == 2, proc.stderr
    report = proc.stderr.splitlines()
    assert report[0] == "error: cannot evaluate:" and report[1].startswith("FAILED scaled/seq")
    assert report[1].endswith("/cam1: RuntimeError: boom on cam1") and "SKIPPED" in proc.stderr
    assert not any(line.startswith("FAILED") for line in report[report.index(next(
        line for line in report if line.startswith("SKIPPED"))):])

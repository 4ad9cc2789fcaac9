"""Progress where stdout is not a terminal, `-v` naming what runs where, and each run's log file."""

from __future__ import annotations

import re
from pathlib import Path

from conftest import mocapflow
from mocapflow.pipeline.storage import Store


def log_file(project: Path, stdout: str) -> Path:
    summary = stdout.strip().splitlines()[-1]
    match = re.fullmatch(r"\d+ executed, \d+ cached, 0 failed, 0 skipped in [\d.]+ s; log (\S+)", summary)
    assert match, summary
    path = project / match.group(1)
    assert path.parent == project / "storage" / "logs" and path.name.startswith("run-") and path.suffix == ".log"
    return path


def test_a_piped_run_prints_a_line_per_stage_and_logs_to_the_storage_root(toy_project):
    project = toy_project()
    proc = mocapflow("run", "--workers", "1", cwd=project)  # stdout is a pipe here
    lines = proc.stdout.strip().splitlines()
    for stage, n in (("frames", 2), ("scaled", 4), ("diffed", 4), ("summed", 2)):
        assert any(re.match(rf"{stage}: {n} partition\(s\) done, {n} executed, 0 cached, 0 failed "
                            r"\([\d.]+ s of work, finished [\d.]+ s into the run\)$", line)
                   for line in lines), proc.stdout
    # a stage's own seconds are its partitions', not the time since the run started
    own = {m[1]: (float(m[2]), float(m[3])) for m in
           (re.match(r"(\w+): .*\(([\d.]+) s of work, finished ([\d.]+) s into the run\)$", line) for line in lines) if m}
    assert all(work <= at * 2 + 0.1 for work, at in own.values()), own  # two workers at most in parallel
    assert len(lines) == 5, proc.stdout  # four stages, then the summary
    assert "INFO" not in proc.stderr  # the console stays at WARNING without -v
    text = log_file(project, proc.stdout).read_text()
    assert text.startswith(f"mocapflow run (run --workers 1) on {project / 'storage'}") and "INFO" in text
    assert re.search(r"scaled\+diffed/seqA/cam0@\S+ ran on worker .+: scaled/seqA/cam0 executed", text), text
    assert "summed: 2 partition(s) done" in text and "12 executed, 0 cached, 0 failed, 0 skipped" in text
    assert Store(str(project / "storage")).stages_on_disk() == ["diffed", "frames", "scaled", "summed"]  # not logs

    again = mocapflow("-v", "run", cwd=project)  # nothing to run: no stage line, still a log of its own
    assert again.stdout.strip().splitlines()[0].startswith("0 executed, 12 cached")
    second = log_file(project, again.stdout)
    assert second != log_file(project, proc.stdout) and "0 executed, 12 cached" in second.read_text()


def test_verbose_says_which_worker_runs_which_partition(toy_project):
    project = toy_project(sequences=("seqA",))
    proc = mocapflow("-v", "run", "--only", "frames", cwd=project)
    assert re.search(r"INFO mocapflow\.pipeline\.scheduler: frames/seqA ran on worker \S+ \(\S+\): frames/seqA executed",
                     proc.stderr), proc.stderr
    assert "running 1 partition(s) of 1 stage(s)" in proc.stderr

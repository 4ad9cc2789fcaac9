"""Verified artifacts: a deleted, truncated, bit-flipped or misplaced chunk is found by `mocapflow verify` and by the
stage that reads it, shown as damaged, and written again, after which the outputs equal a clean run's."""

from __future__ import annotations

import shutil

import pytest

from conftest import assert_same_artifacts, last_json, mocapflow, read_artifacts

DAMAGE = ["deleted", "truncated", "bit-flipped", "copied over"]


def clean_run(project, tmp_path_factory) -> dict:
    """The artifacts of a clean run of ``project``'s catalog, in a copy."""
    ref = tmp_path_factory.mktemp("clean")
    shutil.copytree(project / "data", ref / "data")
    shutil.copy(project / "catalog.yaml", ref / "catalog.yaml")
    mocapflow("run", "--json", cwd=ref)
    return read_artifacts(ref / "storage")


def damage(version, how: str) -> str:
    """Damage the chunk of frames 4-7 of ``value`` in a ``scaled`` version; its key."""
    chunk = version / "data.zarr" / "value" / "c" / "0" / "1" / "0" / "0"
    data = chunk.read_bytes()
    if how == "deleted":
        chunk.unlink()
    elif how == "truncated":
        chunk.write_bytes(data[: len(data) // 2])
    elif how == "bit-flipped":
        chunk.write_bytes(data[:100] + bytes([data[100] ^ 0x01]) + data[101:])
    else:  # the chunk of frames 8-11 over it
        shutil.copy(chunk.parent.parent.parent / "2" / "0" / "0", chunk)
    return "value/c/0/1/0/0"


def scaled_version(project, view: str = "cam0"):
    for version in (project / "storage" / "scaled").iterdir():
        if f'"scaled/seqA/{view}"' in (version / "lineage.json").read_text():
            return version
    raise AssertionError(f"no scaled version of seqA/{view}")


@pytest.mark.parametrize("how", DAMAGE)
def test_verify_finds_the_damage_status_shows_it_and_a_run_rewrites_only_that_region(toy_project, tmp_path_factory,
                                                                                     how):
    project = toy_project(sequences=("seqA",))
    clean = clean_run(project, tmp_path_factory)
    mocapflow("run", "--json", cwd=project)
    chunk = damage(scaled_version(project), how)

    found = mocapflow("verify", cwd=project, check=False)
    assert found.returncode == 1
    assert f"DAMAGED scaled/seqA/cam0 (scaled/{scaled_version(project).name}): 1 chunk(s), in 00000004-00000008" \
        in found.stdout
    assert chunk in found.stdout and ("is missing" if how == "deleted" else "has digest") in found.stdout
    assert "5 intact, 1 damaged, 0 unverified" in found.stdout and "mocapflow run" in found.stderr

    status = mocapflow("status", cwd=project).stdout
    assert "1 damaged" in status and "5 fresh" in status
    assert [line.split() for line in status.splitlines() if line.startswith("scaled")] == [["scaled", "damaged", "fresh"]]

    rerun = last_json(mocapflow("run", "--json", cwd=project))
    assert rerun["executed"] == ["scaled/seqA/cam0"] and rerun["regions"] == {"scaled/seqA/cam0": 1}
    assert_same_artifacts(read_artifacts(project / "storage"), clean)
    assert "6 intact, 0 damaged" in mocapflow("verify", cwd=project).stdout
    assert "6 fresh" in mocapflow("status", cwd=project).stdout


@pytest.mark.parametrize("how", DAMAGE)
def test_a_stage_reading_a_damaged_chunk_fails_naming_it_and_the_fix(toy_project, tmp_path_factory, how):
    project = toy_project(sequences=("seqA",))
    clean = clean_run(project, tmp_path_factory)
    mocapflow("run", "--json", "--until", "scaled", cwd=project)
    version = scaled_version(project)
    chunk = damage(version, how)

    proc = mocapflow("run", "--json", "--keep-going", cwd=project, check=False)
    summary = last_json(proc)
    assert proc.returncode == 1
    assert set(summary["failed"]) == {"diffed/seqA/cam0", "summed/seqA"}  # the readers of scaled/seqA/cam0
    for message in summary["errors"].values():
        assert f"artifact scaled/{version.name} (partition scaled/seqA/cam0)" in message
        assert f"chunk {chunk} of array 'value'" in message
        assert "run `mocapflow verify scaled`" in message and "then `mocapflow run`" in message
        assert "zstd" not in message.lower()

    assert mocapflow("verify", "scaled", cwd=project, check=False).returncode == 1
    rerun = last_json(mocapflow("run", "--json", cwd=project))
    assert set(rerun["executed"]) == {"scaled/seqA/cam0", "diffed/seqA/cam0", "summed/seqA"}
    assert rerun["regions"]["scaled/seqA/cam0"] == 1
    assert_same_artifacts(read_artifacts(project / "storage"), clean)


def test_deleting_complete_does_not_recommit_a_damaged_region(toy_project, tmp_path_factory):
    project = toy_project(sequences=("seqA",))
    clean = clean_run(project, tmp_path_factory)
    mocapflow("run", "--json", cwd=project)
    version = scaled_version(project)
    damage(version, "bit-flipped")
    (version / "_COMPLETE").unlink()  # as a user might, to force a rerun
    rerun = last_json(mocapflow("run", "--json", cwd=project))
    assert rerun["executed"] == ["scaled/seqA/cam0"] and rerun["regions"] == {"scaled/seqA/cam0": 1}
    assert_same_artifacts(read_artifacts(project / "storage"), clean)
    assert "6 intact, 0 damaged" in mocapflow("verify", cwd=project).stdout


def test_a_damaged_template_chunk_rewrites_the_whole_version(toy_project, tmp_path_factory):
    project = toy_project(sequences=("seqA",))
    clean = clean_run(project, tmp_path_factory)
    mocapflow("run", "--json", cwd=project)
    (scaled_version(project) / "data.zarr" / "frame" / "c" / "0").unlink()  # the frame coordinate: every region's
    found = mocapflow("verify", "scaled", cwd=project, check=False)
    assert found.returncode == 1 and "frame/c/0 is missing" in found.stdout and "in 00000000-00000004" in found.stdout
    rerun = last_json(mocapflow("run", "--json", cwd=project))
    assert rerun["executed"] == ["scaled/seqA/cam0"] and rerun["regions"] == {"scaled/seqA/cam0": 5}
    assert_same_artifacts(read_artifacts(project / "storage"), clean)


def test_an_undamaged_store_verifies_clean(toy_project):
    project = toy_project()
    mocapflow("run", "--json", cwd=project)
    before = {p: p.read_bytes() for p in (project / "storage").rglob("*") if p.is_file()}
    every = mocapflow("verify", cwd=project)
    assert every.stdout.strip().splitlines() == ["12 intact, 0 damaged, 0 unverified (written before digests were "
                                                 "recorded)"]
    assert "4 intact, 0 damaged" in mocapflow("verify", "scaled", cwd=project).stdout
    after = {p: p.read_bytes() for p in (project / "storage").rglob("*") if p.is_file()}
    assert after == before  # verifying changes nothing
    assert last_json(mocapflow("run", "--json", cwd=project))["executed"] == []


def test_versions_without_digests_are_reported_unverified_and_still_read(toy_project):
    project = toy_project(sequences=("seqA",))
    mocapflow("run", "--json", "--until", "scaled", cwd=project)
    for digests in (project / "storage").glob("*/*/digests.json"):
        digests.unlink()  # as a version written before digests were recorded
    assert "0 intact, 0 damaged, 3 unverified" in mocapflow("verify", cwd=project).stdout
    assert last_json(mocapflow("run", "--json", cwd=project))["failed"] == []


def test_verify_of_an_unknown_stage_names_the_stages(toy_project):
    project = toy_project(sequences=("seqA",))
    mocapflow("run", "--json", "--until", "frames", cwd=project)
    proc = mocapflow("verify", "scaledd", cwd=project, check=False)
    assert proc.returncode == 2 and "no stored versions of stage 'scaledd'" in proc.stderr and "scaled" in proc.stderr

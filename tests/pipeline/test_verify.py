"""Verified artifacts: a deleted, truncated, bit-flipped or misplaced chunk is found by `mocapflow verify` and by the
stage that reads it, shown as damaged, and written again, after which the outputs equal a clean run's."""

from __future__ import annotations

import shutil

from conftest import assert_same_artifacts, last_json, mocapflow, read_artifacts

DAMAGE = ["deleted", "truncated", "bit-flipped", "copied over"]


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


def scaled_version(project, view: str = "cam0", sequence: str = "seqA"):
    for version in (project / "storage" / "scaled").iterdir():
        if f'"scaled/{sequence}/{view}"' in (version / "lineage.json").read_text():
            return version
    raise AssertionError(f"no scaled version of {sequence}/{view}")


# one kind of damage per partition of `scaled`, so one store shows every kind
DAMAGED = dict(zip(DAMAGE, [("seqA", "cam0"), ("seqA", "cam1"), ("seqB", "cam0"), ("seqB", "cam1")]))


def damage_every_kind(project) -> dict:
    """Damage frames 4-7 of each `scaled` partition, a different way each; partition id -> (version, chunk key)."""
    out = {}
    for how, (seq, view) in DAMAGED.items():
        version = scaled_version(project, view, seq)
        out[f"scaled/{seq}/{view}"] = (version, damage(version, how), how)
    return out


def test_verify_finds_every_kind_of_damage_status_shows_it_and_a_run_rewrites_only_those_regions(toy_run):
    project, _ = toy_run()
    clean = read_artifacts(project / "storage")  # a clean run's artifacts, before the damage
    damaged = damage_every_kind(project)

    found = mocapflow("verify", cwd=project, check=False)
    assert found.returncode == 1
    lines = found.stdout.splitlines()
    for pid, (version, chunk, how) in damaged.items():
        line = next((line for line in lines if line.startswith(f"DAMAGED {pid} ")), None)
        assert line == f"DAMAGED {pid} (scaled/{version.name}): 1 chunk(s), in 00000004-00000008", (how, lines)
        detail = lines[lines.index(line) + 1]
        assert chunk in detail and ("is missing" if how == "deleted" else "has digest") in detail, (how, detail)
    assert "8 intact, 4 damaged, 0 unverified" in found.stdout and "mocapflow run" in found.stderr

    status = mocapflow("status", cwd=project).stdout
    assert "4 damaged" in status and "8 fresh" in status
    assert [line.split()[:2] for line in status.splitlines() if line.startswith("scaled")] == [["scaled", "damaged"]]

    rerun = last_json(mocapflow("run", "--json", cwd=project))
    assert sorted(rerun["executed"]) == sorted(damaged) and rerun["regions"] == {pid: 1 for pid in damaged}
    assert_same_artifacts(read_artifacts(project / "storage"), clean)
    assert "12 intact, 0 damaged" in mocapflow("verify", cwd=project).stdout
    assert "12 fresh" in mocapflow("status", cwd=project).stdout


def test_a_stage_reading_a_damaged_chunk_fails_naming_it_and_the_fix(toy_run):
    project, _ = toy_run()
    clean = read_artifacts(project / "storage")  # a clean run's artifacts; then the project starts afresh
    shutil.rmtree(project / "storage")
    mocapflow("run", "--json", "--until", "scaled", cwd=project)
    damaged = damage_every_kind(project)

    proc = mocapflow("run", "--json", "--keep-going", cwd=project, check=False)
    summary = last_json(proc)
    assert proc.returncode == 1
    readers = {pid.replace("scaled/", "diffed/") for pid in damaged} | {"summed/seqA", "summed/seqB"}
    assert set(summary["failed"]) == readers
    for pid, (version, chunk, how) in damaged.items():
        message = summary["errors"][pid.replace("scaled/", "diffed/")]
        assert f"artifact scaled/{version.name} (partition {pid})" in message, (how, message)
        assert f"chunk {chunk} of array 'value'" in message
        assert "run `mocapflow verify scaled`" in message and "then `mocapflow run`" in message
        assert "zstd" not in message.lower()

    assert mocapflow("verify", "scaled", cwd=project, check=False).returncode == 1
    rerun = last_json(mocapflow("run", "--json", cwd=project))
    assert set(rerun["executed"]) == set(damaged) | readers
    assert all(rerun["regions"][pid] == 1 for pid in damaged)
    assert_same_artifacts(read_artifacts(project / "storage"), clean)


def test_deleting_complete_does_not_recommit_a_damaged_region(toy_run):
    project, _ = toy_run(sequences=("seqA",))
    clean = read_artifacts(project / "storage")  # a clean run's artifacts, before the damage
    version = scaled_version(project)
    damage(version, "bit-flipped")
    (version / "_COMPLETE").unlink()  # as a user might, to force a rerun
    rerun = last_json(mocapflow("run", "--json", cwd=project))
    assert rerun["executed"] == ["scaled/seqA/cam0"] and rerun["regions"] == {"scaled/seqA/cam0": 1}
    assert_same_artifacts(read_artifacts(project / "storage"), clean)
    assert "6 intact, 0 damaged" in mocapflow("verify", cwd=project).stdout


def test_a_damaged_template_chunk_rewrites_the_whole_version(toy_run):
    project, _ = toy_run(sequences=("seqA",))
    clean = read_artifacts(project / "storage")  # a clean run's artifacts, before the damage
    (scaled_version(project) / "data.zarr" / "frame" / "c" / "0").unlink()  # the frame coordinate: every region's
    found = mocapflow("verify", "scaled", cwd=project, check=False)
    assert found.returncode == 1 and "frame/c/0 is missing" in found.stdout and "in 00000000-00000004" in found.stdout
    rerun = last_json(mocapflow("run", "--json", cwd=project))
    assert rerun["executed"] == ["scaled/seqA/cam0"] and rerun["regions"] == {"scaled/seqA/cam0": 5}
    assert_same_artifacts(read_artifacts(project / "storage"), clean)


def test_an_undamaged_store_verifies_clean(toy_run):
    project, _ = toy_run()
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


def test_verify_of_an_unknown_stage_names_the_stages(toy_run):
    project, _ = toy_run(until="frames", sequences=("seqA",))
    proc = mocapflow("verify", "scaledd", cwd=project, check=False)
    assert proc.returncode == 2 and "no stored versions of stage 'scaledd'" in proc.stderr and "scaled" in proc.stderr

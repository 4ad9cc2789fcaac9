"""Bad input at the door: every reader a user's file reaches (C3D and TRC markers, BVH clips alone and through the
studio, ASF/AMC takes, Qualisys / Pose2Sim / OpenCV calibrations, a DeepMoCap view, UUO prior files, the catalog),
fed seeded damaged copies of small real files, reads each one or raises the project's own error naming the file: no
other exception, no hang (each read has a time limit), no memory blow-up (the worker's address space is capped).

The mutator, the base files and the readers are benchmarks/fuzz_readers.py's, which runs many more mutants
(``python benchmarks/fuzz_readers.py --count 500``); here a CI-sized share of them."""

from __future__ import annotations

import random
import sys

import pytest

from conftest import ROOT

sys.path.insert(0, str(ROOT / "benchmarks"))
import fuzz_readers  # noqa: E402

COUNT = 60  # mutants per format
SEED = 0
TIMEOUT_S = 20.0  # a read of these small files takes well under a second
NEEDS_SHARED = {"qca", "toml", "opencv"}  # base files from ../shared/data (the BVH readers fall back on a test clip)


def _param(name):
    marks = [pytest.mark.needs_shared] if name in NEEDS_SHARED else []
    return pytest.param(name, marks=marks, id=name)


@pytest.fixture(scope="module")
def pool():
    pool = fuzz_readers.Pool(list(fuzz_readers.FORMATS), timeout=TIMEOUT_S)
    yield pool
    pool.close()


@pytest.mark.parametrize("name", [_param(n) for n in fuzz_readers.FORMATS])
def test_every_damaged_file_reads_or_is_refused_naming_it(name, pool, tmp_path):
    result = fuzz_readers.fuzz(name, COUNT, SEED, pool, tmp_path)
    assert sum(result.counts.values()) == COUNT
    assert result.counts["read"] + result.counts["clean"] == COUNT - len(result.failures)
    failures = result.failures
    shown = "\n\n".join(f"--- {outcome}: {what}\n{detail}" for what, outcome, detail in failures[:3])
    assert not failures, f"{len(failures)} of {COUNT} damaged {name} files were not refused cleanly " \
                         f"({result.counts}):\n{shown}"


@pytest.mark.parametrize("name", [_param(n) for n in fuzz_readers.FORMATS])
def test_the_undamaged_base_files_read(name, pool, tmp_path):
    cases = fuzz_readers.FORMATS[name].cases()
    assert cases
    for k, case in enumerate(cases):
        folder = tmp_path / str(k)
        fuzz_readers.write_case(folder, case.files)
        assert pool.read(name, folder, case, case.targets[0]) == ("read", ""), case.name


def test_the_mutator_is_seeded_and_damages_what_it_is_given():
    data = b"Frames: 30\nFrame Time: 0.0083\n" + b"1.0 2.0 3.0\n" * 50
    assert fuzz_readers.mutate(data, random.Random(7), "text") == fuzz_readers.mutate(data, random.Random(7), "text")
    rng = random.Random(1)
    mutants = [fuzz_readers.mutate(data, rng, kind)[0] for kind in ("text", "binary", "c3d") for _ in range(30)]
    assert sum(m != data for m in mutants) >= 85

"""Cache keys: what flips a partition's key (params, code version, schema version, upstream, raw input, weights)
and what does not (run-time settings, another stage's params, the storage root); one helper opens an artifact."""

from __future__ import annotations

import dataclasses

import pytest

from conftest import PLUGINS, ROOT, write_raw_zarr
from mocapflow.pipeline import registry
from mocapflow.pipeline.catalog import load_catalog
from mocapflow.pipeline.errors import PlanError
from mocapflow.pipeline.plan import build_plan, cache_params, partition_bytes


@pytest.fixture(autouse=True)
def _plugins(monkeypatch):
    monkeypatch.syspath_prepend(str(PLUGINS))


def keys(folder, *overrides) -> dict[str, str]:
    catalog = load_catalog(folder / "catalog.yaml", tuple(overrides))
    return {pid: item.key for pid, item in build_plan(catalog).items.items()}


def changed(a: dict, b: dict) -> set[str]:
    return {pid for pid in a if a[pid] != b[pid]}


def stage_of(pids) -> set[str]:
    return {pid.split("/")[0] for pid in pids}


def test_keys_are_stable_and_a_param_flips_its_stage_and_downstream_only(toy_project):
    folder = toy_project()
    base = keys(folder)
    assert base == keys(folder)  # the same catalog, the same keys
    assert stage_of(changed(base, keys(folder, "stages.scaled.params.factor=4"))) == {"scaled", "diffed", "summed"}
    assert changed(base, keys(folder, "stages.scaled.params.factor=3.0")) == set()  # 3 and 3.0 are one value


def test_the_storage_root_and_region_size_are_not_part_of_the_key(toy_project):
    folder = toy_project()
    base = keys(folder)
    assert changed(base, keys(folder, "storage.root=elsewhere/", "storage.region_frames=8")) == set()


def test_a_new_code_version_flips_that_task_only(toy_project, monkeypatch):
    folder = toy_project()
    base = keys(folder)
    monkeypatch.setitem(registry._REGISTRY, "diff", dataclasses.replace(registry.get("diff"), version="2"))
    assert stage_of(changed(base, keys(folder))) == {"diffed"}


def test_new_raw_data_flips_that_sequence_only(toy_project):
    folder = toy_project()
    base = keys(folder)
    write_raw_zarr(folder / "data" / "seqB.zarr", seed=7)
    flipped = changed(base, keys(folder))
    assert flipped and all("/seqB" in pid for pid in flipped)
    assert {"frames/seqB", "summed/seqB"} <= flipped


def test_runtime_params_stay_out_of_the_key():
    from mocapflow.tasks.deepmocap.heatmaps import HeatmapConfig

    assert cache_params(HeatmapConfig(batch=1)) == cache_params(HeatmapConfig(batch=32))
    assert cache_params(HeatmapConfig(precision="bfloat16")) != cache_params(HeatmapConfig())
    assert "batch" not in cache_params(HeatmapConfig())


def test_a_runtime_setting_keeps_every_key(tmp_path):
    catalog = (ROOT / "catalog.yaml").read_text()
    (tmp_path / "catalog.yaml").write_text(catalog)
    base = keys(tmp_path)
    assert changed(base, keys(tmp_path, "stages.heatmaps.params.batch=2")) == set()
    assert stage_of(changed(base, keys(tmp_path, "stages.heatmaps.params.precision=float32"))) == {
        "heatmaps", "reflectors2d", "markers3d", "smoothed", "skeleton", "template", "checked", "poses",
        "reflectors2d_refined"}


def test_a_weights_file_is_hashed_into_the_key(tmp_path):
    (tmp_path / "catalog.yaml").write_text((ROOT / "catalog.yaml").read_text())
    shipped = (ROOT / "models" / "deepmocap_fcn.pt").read_bytes()
    (tmp_path / "a.pt").write_bytes(shipped)
    (tmp_path / "b.pt").write_bytes(shipped + b"\0")
    base = keys(tmp_path)
    same = keys(tmp_path, "stages.heatmaps.params.weights=a.pt")
    other = keys(tmp_path, "stages.heatmaps.params.weights=b.pt")
    assert stage_of(changed(base, same)) == {"heatmaps", "reflectors2d", "markers3d", "smoothed", "skeleton",
                                             "template", "checked", "poses", "reflectors2d_refined"}  # the path is a parameter too
    assert changed(same, other) == changed(base, same)  # the bytes flip it


def test_work_items_carry_the_resolved_stage_not_the_catalog(toy_project):
    folder = toy_project()
    catalog = load_catalog(folder / "catalog.yaml")
    plan = build_plan(catalog)
    item = plan.item("scaled", "seqA", "cam0")
    assert item.spec is registry.get("scale") and item.stage.schema.name == "toy_view"
    assert item.root == catalog.root and item.plugins == ("toytasks",)
    assert item.dataset is None and plan.item("frames", "seqA").dataset.kind == "zarr"
    assert not any(isinstance(v, type(catalog)) for v in vars(item).values())
    assert item.upstream["frames"].schema.name == "raw_sequence"


def test_an_unknown_partition_names_the_nearest(toy_project):
    plan = build_plan(load_catalog(toy_project() / "catalog.yaml"))
    with pytest.raises(PlanError, match=r"no partition 'scaled/seqA/cam9' .*did you mean 'scaled/seqA/cam[01]'"):
        plan.item("scaled", "seqA", "cam9")


def test_a_partition_is_sized_by_the_image_its_reader_states(tmp_path):
    """The suit's grey cameras (1536 x 2048 here) size its image partitions, not another sensor's."""
    (tmp_path / "catalog.yaml").write_text(
        "storage: {root: storage/}\n"
        "datasets:\n"
        "  suit: {kind: studio_suit, cameras: {count: 2}, defaults: {frames: 6}, sequences: {s1: {motion: side_steps}}}\n"
        "stages:\n"
        "  images: {task: ingest_suit, dataset: suit}\n"
        "  corners: {task: find_corners, inputs: [images]}\n")
    catalog = load_catalog(tmp_path / "catalog.yaml")
    plan = build_plan(catalog)
    sequences = {s.id: s for s in plan.sequences}
    assert sequences["s1"].image == (2048, 1536)
    corners = [i for pid, i in plan.items.items() if pid.startswith("corners/")]
    assert corners and all(partition_bytes(i, sequences) == min(6, i.stage.region_frames) * 1 * 2048 * 1536 * 4
                           for i in corners)
    with pytest.raises(PlanError, match="the biggest of"):
        build_plan(load_catalog(tmp_path / "catalog.yaml", ("storage.max_partition_bytes=1000000",)))

"""Catalog loading: clear errors with line numbers, overrides, path confinement; bad catalogs write nothing."""

from __future__ import annotations

import pytest

from conftest import PLUGINS, last_json, mocapflow, read_artifacts
from mocapflow.pipeline.catalog import load_catalog
from mocapflow.pipeline.errors import CatalogError


@pytest.fixture(autouse=True)
def _plugins_importable(monkeypatch):
    monkeypatch.syspath_prepend(str(PLUGINS))


def edit(project, old, new):
    path = project / "catalog.yaml"
    text = path.read_text()
    assert old in text
    path.write_text(text.replace(old, new))
    return path


def test_valid_catalog_orders_stages_and_fills_inputs(toy_project):
    project = toy_project()
    catalog = load_catalog(project / "catalog.yaml")
    assert list(catalog.stages) == ["frames", "scaled", "diffed", "summed"]
    assert catalog.stages["diffed"].inputs == {"scaled": "scaled"}
    assert catalog.stages["scaled"].params.factor == 3.0
    assert catalog.ancestors("diffed") == ["frames", "scaled", "diffed"]


@pytest.mark.parametrize(
    "old,new,message",
    [
        ("task: scale,", "task: scal,", "(line 7): stages.scaled.task: unknown task 'scal' (did you mean 'scale'?)"),
        ("factor: 3", "fctor: 3", "(line 7): stages.scaled.params.fctor: task 'scale' has no parameter 'fctor' "
                                  "(did you mean 'factor'?)"),
        ("factor: 3", "factor: three", "stages.scaled.params.factor: expected float, got str 'three'"),
        ("inputs: [scaled]}\n  summed", "inputs: [scaled_typo]}\n  summed",
         "input 'scaled' names stage 'scaled_typo', which is not declared (did you mean 'scaled'?)"),
        ("stages:", "stges:", "unknown key 'stges' (did you mean 'stages'?)"),
        ("kind: zarr", "kind: zar", "unknown dataset kind 'zar' (did you mean 'zarr'?)"),
        ("region_frames: 4", "region_frames: -4", "storage.region_frames: expected a positive integer, got -4"),
        ("  scaled: {task", "  on: {task", "stages: key True is not a name (YAML reads on, off, yes, no, true, false "
                                         "as booleans and null or ~ as nothing); quote it, e.g. 'on':"),
    ],
)
def test_bad_catalog_names_key_line_and_fix(toy_project, old, new, message):
    project = toy_project()
    edit(project, old, new)
    with pytest.raises(CatalogError) as err:
        load_catalog(project / "catalog.yaml")
    assert message in str(err.value)


def test_cycle_is_reported_with_its_path(toy_project):
    project = toy_project()
    with pytest.raises(CatalogError, match=r"stages form a cycle: (diffed -> d2 -> diffed|d2 -> diffed -> d2)"):
        load_catalog(project / "catalog.yaml", ("stages.diffed.inputs=[d2]", "stages.d2.task=diff",
                                                "stages.d2.inputs=[diffed]"))


def test_schema_mismatch_between_stages(toy_project):
    project = toy_project()
    with pytest.raises(CatalogError, match="must be a 'raw_sequence' artifact, but stage 'diffed'"):
        load_catalog(project / "catalog.yaml", ("stages.scaled.inputs=[diffed]",))


def test_set_overrides_any_value_and_is_named_in_errors(toy_project):
    project = toy_project()
    catalog = load_catalog(project / "catalog.yaml", ("stages.scaled.params.factor=5", "stages.scaled.task=scale_plus"))
    assert catalog.stages["scaled"].params.factor == 5.0
    assert catalog.stages["scaled"].task == "scale_plus"
    with pytest.raises(CatalogError, match=r"\(--set\): stages.scaled.params.nope"):
        load_catalog(project / "catalog.yaml", ("stages.scaled.params.nope=1",))
    with pytest.raises(CatalogError, match="expected dotted.key=value"):
        load_catalog(project / "catalog.yaml", ("stages.scaled.params.factor",))


def test_dataset_path_must_stay_inside_data_roots(toy_project, tmp_path):
    project = toy_project()
    edit(project, "path: data", "path: ../../etc")
    with pytest.raises(CatalogError, match="outside the declared data_roots"):
        mocapflow_plan(project)


def mocapflow_plan(project):
    from mocapflow.pipeline.plan import build_plan

    return build_plan(load_catalog(project / "catalog.yaml"))


def test_plan_groups_work_items_by_stage_in_plan_order(toy_project):
    plan = mocapflow_plan(toy_project())
    grouped = plan.by_stage()
    assert list(grouped) == ["frames", "scaled", "diffed", "summed"]
    for stage, items in grouped.items():
        assert items == plan.for_stages([stage])
        assert {i.partition.stage for i in items} == {stage}
    assert sum(map(len, grouped.values())) == len(plan.items)
    assert len(grouped["scaled"]) > 1  # one item per (sequence, view) partition


def test_bad_catalog_in_cli_leaves_artifacts_untouched(toy_project):
    project = toy_project()
    mocapflow("run", "--json", cwd=project)
    before = read_artifacts(project / "storage")
    listing = sorted(p.relative_to(project) for p in (project / "storage").rglob("*"))
    proc = mocapflow("run", "--set", "stages.scaled.params.factr=9", cwd=project, check=False)
    assert proc.returncode == 2
    assert "did you mean 'factor'" in proc.stderr
    assert sorted(p.relative_to(project) for p in (project / "storage").rglob("*")) == listing
    after = read_artifacts(project / "storage")
    assert before.keys() == after.keys()
    assert last_json(mocapflow("run", "--json", cwd=project))["executed"] == []


def test_a_task_naming_an_unregistered_schema_is_refused_at_load(toy_project, monkeypatch):
    import dataclasses

    from mocapflow.pipeline import registry
    from mocapflow.schemas import UnknownSchema

    project = toy_project()
    load_catalog(project / "catalog.yaml")  # imports the toy plugin, which registers scale and toy_view
    scale = registry.get("scale")
    monkeypatch.setitem(registry._REGISTRY, "scale_out", dataclasses.replace(scale, name="scale_out", output="toy_veiw"))
    monkeypatch.setitem(registry._REGISTRY, "scale_in", dataclasses.replace(scale, name="scale_in",
                                                                            inputs={"frames": "raw_sequense"}))
    with pytest.raises(CatalogError) as err:
        load_catalog(project / "catalog.yaml", ("stages.scaled.task=scale_out",))
    assert str(err.value).startswith(
        "catalog.yaml (--set): stages.scaled.task: task 'scale_out' writes its output as schema 'toy_veiw', which is "
        "not registered: unknown schema 'toy_veiw' (did you mean 'toy_view'?); registered schemas: [")
    assert "'toy_sequence', 'toy_view'" in str(err.value)
    assert isinstance(err.value.__cause__, UnknownSchema)
    with pytest.raises(CatalogError, match=r"task 'scale_in' reads input 'frames' as schema 'raw_sequense', which is not "
                                           r"registered: unknown schema 'raw_sequense' \(did you mean 'raw_sequence'\?\)"):
        load_catalog(project / "catalog.yaml", ("stages.scaled.task=scale_in",))

"""The registry: a task's function must take its inputs, its config and its weights, checked when it is
registered (a Lazy one when first imported); every built-in task passes; params are checked and coerced."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

import pytest
import xarray as xr

from mocapflow.pipeline import registry
from mocapflow.pipeline.errors import CatalogError

registry.systems()  # the built-in systems registered before a test swaps the registry for a copy


@dataclass(frozen=True)
class Params:
    factor: float = 2.0
    batch: int = field(default=4, metadata={"runtime": True})


def good(frames: xr.Dataset, config: Params) -> xr.Dataset:
    return frames


def spec(fn, **extra) -> registry.TaskSpec:
    return registry.TaskSpec(name="probe", fn=fn, version="1", params=Params, output="toy", partition="view",
                             inputs={"frames": "raw_sequence"}, **extra)


def test_a_task_taking_its_inputs_and_config_registers(monkeypatch):
    monkeypatch.setattr(registry, "_REGISTRY", dict(registry._REGISTRY))
    assert registry.register(spec(good)).fn is good
    assert registry.get("probe").fn is good


@pytest.mark.parametrize("fn", [
    lambda frames, *, factor, batch: frames,  # config exploded into keywords
    lambda frames, config, extra: frames,  # a parameter the engine never passes
    lambda frame, config: frame,  # a misspelt input role
    lambda frames, config, **kwargs: frames,  # keywords swallowed
])
def test_a_task_whose_signature_disagrees_is_refused_at_registration(fn):
    with pytest.raises(CatalogError, match=r"its function takes .* engine calls it with \(frames, config\)"):
        registry.register(spec(fn))


def test_weight_parameters_come_after_config():
    def weighted(frames, config, weights):
        return frames

    registry.check_signature("weighted", weighted, registry.task_parameters(spec(weighted, weights_params=("weights",))))
    with pytest.raises(CatalogError, match="weights"):
        registry.register(spec(good, weights_params=("weights",)))


def test_a_lazy_task_is_checked_when_first_imported(monkeypatch):
    monkeypatch.setattr(registry, "_REGISTRY", dict(registry._REGISTRY))
    lazy = registry.register(spec(registry.Lazy("mocapflow.tasks.deepmocap.masks", "masks"))).fn
    assert lazy.roles == ("frames", "config")
    with pytest.raises(CatalogError, match="masks.masks"):  # masks takes `frames`, not `depth`
        registry.Lazy("mocapflow.tasks.deepmocap.masks", "masks", roles=("depth", "config")).resolve()


def test_params_must_be_a_frozen_dataclass():
    @dataclass
    class Loose:
        x: int = 1

    with pytest.raises(CatalogError, match="frozen"):
        registry.register(dataclasses.replace(spec(good), params=Loose))
    with pytest.raises(CatalogError, match="frozen dataclass"):
        registry.register(dataclasses.replace(spec(good), params=dict))


def test_every_builtin_task_takes_its_inputs_config_and_weights():
    for name in registry.names():
        task = registry.get(name)
        if task.fn is None:
            assert task.source
            continue
        fn = task.fn.resolve() if isinstance(task.fn, registry.Lazy) else task.fn
        registry.check_signature(name, fn, registry.task_parameters(task))


def test_runtime_fields_are_the_marked_ones():
    assert registry.runtime_fields(Params) == ("batch",)
    assert registry.runtime_fields(registry.get("fcn_heatmaps").params) == ("batch",)
    assert registry.runtime_fields(registry.get("train_fcn").params) == ("workers", "checkpoint_every")
    assert registry.runtime_fields(registry.get("primal_dual").params) == ("device",)


def test_build_params_coerces_and_names_the_bad_key():
    built = registry.build_params(spec(good), {"factor": 3, "batch": 2}, where=lambda k: f"stages.probe.{k}")
    assert built == Params(factor=3.0, batch=2) and isinstance(built.factor, float)
    with pytest.raises(CatalogError, match=r"stages\.probe\.factr: .* no parameter 'factr' \(did you mean 'factor'\?\)"):
        registry.build_params(spec(good), {"factr": 3}, where=lambda k: f"stages.probe.{k}")
    with pytest.raises(CatalogError, match=r"batch: expected int, got True"):
        registry.build_params(spec(good), {"batch": True})
    # YAML 1.1 reads an exponent without a dot as a string: a float field takes it, a word stays refused
    assert registry.build_params(spec(good), {"factor": "5e-3"}).factor == 0.005
    assert registry.build_params(spec(good), {"factor": "-1E+2"}).factor == -100.0
    with pytest.raises(CatalogError, match=r"factor: expected float, got str 'e5'"):
        registry.build_params(spec(good), {"factor": "e5"})


def test_an_unknown_task_suggests_the_nearest():
    with pytest.raises(CatalogError, match=r"unknown task 'kalmann' \(did you mean 'kalman'\?\)"):
        registry.get("kalmann")


def test_planning_imports_no_torch():
    # every CLI call and every worker process plans: torch (2 s to import) waits until a task that needs it runs
    import subprocess
    import sys

    code = ("import sys; from mocapflow.cli import commands; from mocapflow.pipeline import registry; "
            "registry.import_plugins(()); registry.systems(); "
            "print(sorted(m for m in ('torch', 'anny') if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "[]"
    assert registry.get("read_codes").fn.resolve()  # the stage itself still imports


def test_a_checkpointing_task_takes_checkpoint_and_only_a_training_may_stream_or_keep_one(monkeypatch):
    monkeypatch.setattr(registry, "_REGISTRY", dict(registry._REGISTRY))

    def trains(frames: xr.Dataset, config: Params, checkpoint) -> xr.Dataset:
        return frames

    per_dataset = dataclasses.replace(spec(trains), partition="dataset", checkpoints=True,
                                      streams={"frames": ("image",)})
    assert registry.task_parameters(per_dataset) == ("frames", "config", "checkpoint")
    registry.register(per_dataset)
    with pytest.raises(CatalogError, match="takes \\(frames, config, checkpoint\\) but the engine calls it with "
                                           "\\(frames, config\\)"):
        registry.register(spec(trains))
    for extra in ({"checkpoints": True}, {"streams": {"frames": ("image",)}}):
        with pytest.raises(CatalogError, match="partitioned per 'view' but declares .* only a per-dataset task"):
            registry.register(spec(trains, **extra))


def test_two_systems_adding_one_command_are_refused_and_a_command_loads_on_demand(monkeypatch):
    registry.systems()  # the built-ins first, then the two
    monkeypatch.setattr(registry, "_SYSTEMS", dict(registry._SYSTEMS))
    registry.register_system(registry.System(name="one", commands={"hello": registry.Command("json", "dumps")}))
    assert registry.commands()["hello"] == ("one", registry.Command("json", "dumps"))
    assert registry.commands()["hello"][1].load()([1]) == "[1]"
    assert registry.commands()["synth"][0] == "deepmocap"
    registry.register_system(registry.System(name="two", commands={"hello": registry.Command("json", "loads")}))
    with pytest.raises(CatalogError, match="systems 'one' and 'two' both add the command 'hello'"):
        registry.commands()
    with pytest.raises(CatalogError, match="command json:no_such cannot be loaded"):
        registry.Command("json", "no_such").load()

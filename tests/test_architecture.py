"""The layers of the house, as import-linter contracts generated from the registered systems: the command line above
the systems, the systems above the presentation (report, compare page, the evaluation's tables, the 3D viewer), the
presentation above the file formats and the engine core, the core above the kernels and the schemas; the
presentation, the core and the file formats import no system and no system's kernels; each system (its package
systems/S and its kernels tasks/S) imports no other system's package or kernels; the shared kernels (tasks/shared)
import no system's. A package named in FLOORS (systems/F and tasks/F) is a shared floor instead, registered by no
one: any system may use it (the studio: its takes, generic cameras, lights and renderers; each system films a take
from its own package and registers that dataset kind itself), and it imports no system's package or kernels.
Checked over every import, those inside functions too.

The in-repo systems are those of the registry's entry points (pipeline/registry.py) whose module is under
mocapflow.systems, so a new system is protected as soon as it is registered, with no list to edit here; every
package under systems/ must be one or a floor, and every package under tasks/ one's kernels, a floor's or the shared
ones. pyproject.toml's
[tool.importlinter] section (for `lint-imports` by hand) must equal the generated one: `python
tests/test_architecture.py` prints it. A task's function, `Lazy` ones too (a string no contract sees), must live in
its own system's kernels or the shared ones. Each contract is shown to bite: a copy of the tree with one forbidden
import planted per contract breaks every one, naming the planted import."""

from __future__ import annotations

import dataclasses
import importlib
import importlib.util
import json
import os
import shutil
import subprocess
import sys
import tomllib
from importlib.metadata import entry_points
from pathlib import Path

import pytest

from mocapflow.pipeline import registry

ROOT = Path(__file__).parents[1]
SHARED_KERNELS = "mocapflow.tasks.shared"
LAYERS = ["mocapflow.cli", "mocapflow.systems", "mocapflow.presentation", "mocapflow.formats", "mocapflow.pipeline",
          "mocapflow.tasks", "mocapflow.schemas"]
ROOT_PACKAGES = [*LAYERS, "mocapflow.models"]

LAYERS_CONTRACT = "layers: cli > systems > presentation > formats > engine core > kernels > schemas"
CORE_CONTRACT = "the engine core imports no system's kernels"
PRESENTATION_CONTRACT = "the presentation imports no system and no system's kernels"
FORMATS_CONTRACT = "the file formats import no system and no system's kernels"
SHARED_CONTRACT = "the shared kernels import no system's kernels"
# Shared floors of the systems, registered by no one: their package and kernels may be imported by any system
FLOORS = ("studio",)

# Imports that break generated contracts today, let stand by name until they are moved: each is ignored by every
# contract that forbids the module it imports and whose modules may import its importer (the layers permitting): the
# systems that import it through its importer too. Once one is gone, import-linter stops with "No matches for
# ignored import": delete it here and in pyproject.toml.
KNOWN_BREAKS: list[str] = []


@dataclasses.dataclass(frozen=True)
class InRepoSystem:
    name: str  # the package's last name: systems/<name>, tasks/<name>
    package: str  # mocapflow.systems.<name>
    kernels: str | None  # mocapflow.tasks.<name>, where that package exists
    system: registry.System | None  # None: a floor

    @property
    def modules(self) -> list[str]:
        return [self.package, *([self.kernels] if self.kernels else [])]


def system_contract(system: InRepoSystem) -> str:
    if system.name in FLOORS:
        return f"the {system.name} floor imports no system's package or kernels"
    return f"system {system.name} imports no other system's package or kernels"


def forbidden_for(system: InRepoSystem, systems: list[InRepoSystem]) -> list[str]:
    """What a system may not import: every other system's package and kernels, a shared floor's excepted (a floor
    itself may import none)."""
    return [m for other in systems if other is not system and (system.name in FLOORS or other.name not in FLOORS)
            for m in other.modules]


def kernels_of(name: str) -> str | None:
    kernels = f"mocapflow.tasks.{name}"
    return kernels if importlib.util.find_spec(kernels) else None


def in_repo_systems() -> list[InRepoSystem]:
    """The registered systems whose entry point lies under mocapflow.systems, in the registry's order, then the
    floors."""
    registered = registry.systems()
    found = []
    for point in sorted(entry_points(group=registry.ENTRY_POINT_GROUP), key=lambda p: p.name):
        parts = point.module.split(".")
        if parts[:2] != ["mocapflow", "systems"] or len(parts) < 3:
            continue  # a plug-in installed from elsewhere
        system = point.load()
        assert any(system is s for s in registered), f"entry point {point.name} is not registered"
        assert parts[2] not in FLOORS, f"{point.name}: the floor systems/{parts[2]} is no system to register"
        found.append(InRepoSystem(parts[2], ".".join(parts[:3]), kernels_of(parts[2]), system))
    return found + [InRepoSystem(name, f"mocapflow.systems.{name}", kernels_of(name), None) for name in FLOORS]


def subpackages(package: str) -> set[str]:
    spec = importlib.util.find_spec(package)
    return {p.name for where in spec.submodule_search_locations for p in Path(where).iterdir()
            if (p / "__init__.py").is_file()}


def within(module: str, package: str) -> bool:
    return module == package or module.startswith(package + ".")


def layer(module: str) -> int:
    """The place of a module's layer, from the top (the layers contract keeps a module from importing upwards)."""
    return next(i for i, package in enumerate(LAYERS) if within(module, package))


def contracts_config(systems: list[InRepoSystem]) -> dict:
    """The [tool.importlinter] section for these systems."""
    kernels = [s.kernels for s in systems if s.kernels]
    contracts = [
        {"name": LAYERS_CONTRACT, "type": "layers", "layers": LAYERS},
        {"name": CORE_CONTRACT, "type": "forbidden", "source_modules": ["mocapflow.pipeline"],
         "forbidden_modules": ["mocapflow.systems", *kernels]},
        {"name": PRESENTATION_CONTRACT, "type": "forbidden", "source_modules": ["mocapflow.presentation"],
         "forbidden_modules": ["mocapflow.systems", *kernels]},
        {"name": FORMATS_CONTRACT, "type": "forbidden", "source_modules": ["mocapflow.formats"],
         "forbidden_modules": ["mocapflow.systems", *kernels]},
        {"name": SHARED_CONTRACT, "type": "forbidden", "source_modules": [SHARED_KERNELS], "forbidden_modules": kernels},
    ]
    for system in systems:
        contracts.append({"name": system_contract(system), "type": "forbidden", "source_modules": system.modules,
                          "forbidden_modules": forbidden_for(system, systems)})
    for contract in contracts:
        ignored = [known for known in KNOWN_BREAKS for importer, imported in [known.split(" -> ")]
                   if any(within(imported, m) for m in contract.get("forbidden_modules", ()))
                   and any(layer(m) <= layer(importer) for m in contract["source_modules"])]
        if ignored:
            contract["ignore_imports"] = ignored
    return {"root_packages": ROOT_PACKAGES, "include_external_packages": False, "contracts": contracts}


def toml_section(config: dict) -> str:
    """The section as TOML, lists wrapped at 120 characters."""

    def value(key: str, v) -> str:
        if isinstance(v, bool):
            return "true" if v else "false"
        if isinstance(v, str):
            return json.dumps(v)
        lines, line = [], "["
        for i, item in enumerate(v):
            word = json.dumps(item) + ("," if i < len(v) - 1 else "")
            if line.strip("[") and len(key) + 3 + len(line) + 1 + len(word) > 119:
                lines.append(line)
                line = " " * (len(key) + 4)
            elif line.strip("[ "):
                line += " "
            line += word
        return "\n".join([*lines, line + "]"])

    out = ["[tool.importlinter]"]
    out += [f"{k} = {value(k, v)}" for k, v in config.items() if k != "contracts"]
    for contract in config["contracts"]:
        out += ["", "[[tool.importlinter.contracts]]"] + [f"{k} = {value(k, v)}" for k, v in contract.items()]
    text = "\n".join(out) + "\n"
    assert tomllib.loads(text)["tool"]["importlinter"] == config
    return text


# Run in a fresh interpreter, so that the import graph is built from the tree found on its path (a copy's, in the
# planted test) and not from the modules this process has imported. create_report is import-linter's API;
# lint-imports registers the built-in contract types before calling it.
WORKER = r"""
import importlib.util, json, sys
from importlinter import api  # noqa: F401  (configures import-linter, as lint-imports does)
from importlinter.application import use_cases

def links(node):
    if isinstance(node, dict):
        if {"importer", "imported", "line_numbers"} <= node.keys():
            yield node["importer"], node["imported"]
        for v in node.values():
            yield from links(v)
    elif isinstance(node, (list, tuple)):
        for v in node:
            yield from links(v)

use_cases._register_built_in_contract_types()
options = use_cases.read_user_options(sys.argv[1])
report = use_cases.create_report(options, cache_dir=None)
print(json.dumps({
    "origins": {p: importlib.util.find_spec(p).origin for p in options.session_options["root_packages"]},
    "invalid": {name: str(e) for name, e in report.invalid_contract_options.items()},
    "contracts": {c.name: {"kept": check.kept, "links": sorted(set(links(check.metadata)))}
                  for c, check in report.get_contracts_and_checks()},
}))
"""


def check_contracts(config: dict, folder: Path, tree: Path | None = None) -> dict:
    """Check ``config`` (written to ``folder``) over the installed tree, or over ``tree`` (a folder holding a
    ``mocapflow`` copy): origins of the root packages, invalid contracts, and per contract whether it is kept and
    the imports that break it ((importer, imported) pairs)."""
    path = folder / "importlinter.toml"
    path.write_text(toml_section(config))
    env = dict(os.environ)
    if tree is not None:
        env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(tree), env.get("PYTHONPATH")]))
    proc = subprocess.run([sys.executable, "-c", WORKER, str(path)], cwd=tree or ROOT, env=env, capture_output=True,
                          text=True, timeout=300)
    assert proc.returncode == 0, (
        f"import-linter could not check the contracts:\n{proc.stderr[-4000:]}\n(if it names an ignored import with no "
        "match, that known break is fixed: delete it from KNOWN_BREAKS in tests/test_architecture.py and pyproject.toml)")
    result = json.loads(proc.stdout)
    assert not result["invalid"], result["invalid"]
    result["contracts"] = {name: {"kept": c["kept"], "links": {tuple(link) for link in c["links"]}}
                           for name, c in result["contracts"].items()}
    return result


def broken(result: dict) -> str:
    return "\n".join(f"{name} BROKEN:\n" + "\n".join(f"  {a} -> {b}" for a, b in sorted(c["links"]))
                     for name, c in result["contracts"].items() if not c["kept"])


@pytest.fixture(scope="module")
def systems() -> list[InRepoSystem]:
    return in_repo_systems()


def test_every_system_package_is_a_registered_system(systems):
    names = {s.name for s in systems}
    assert {"deepmocap", "uuo", "suit", "studio"} <= names
    unregistered = subpackages("mocapflow.systems") - names
    assert not unregistered, (f"systems/{sorted(unregistered)} are not registered systems (nor FLOORS): add each to "
                              "[project.entry-points.\"mocapflow.systems\"] in pyproject.toml and pip install -e . "
                              "(its contracts are generated from the registry)")
    strays = subpackages("mocapflow.tasks") - names - {SHARED_KERNELS.rsplit(".", 1)[1]}
    assert not strays, f"tasks/{sorted(strays)} are kernels of no registered system: name them after theirs"


def test_every_import_contract_is_kept(systems, tmp_path):
    config = contracts_config(systems)
    result = check_contracts(config, tmp_path)
    assert all(origin.startswith(str(ROOT)) for origin in result["origins"].values()), result["origins"]
    assert set(result["contracts"]) == {c["name"] for c in config["contracts"]}
    assert all(c["kept"] for c in result["contracts"].values()), broken(result)


def test_pyproject_holds_the_generated_contracts(systems):
    config = contracts_config(systems)
    with open(ROOT / "pyproject.toml", "rb") as f:
        written = tomllib.load(f).get("tool", {}).get("importlinter")
    assert written == config, ("pyproject.toml's [tool.importlinter] is not the one generated from the registered "
                               "systems; replace it with this (python tests/test_architecture.py prints it):\n\n"
                               + toml_section(config))


def plants(systems: list[InRepoSystem]) -> list[tuple[str, str, str]]:
    """One or more forbidden imports per contract: (contract, planted module, the module it imports)."""
    first = systems[0]
    planted = [(LAYERS_CONTRACT, "mocapflow.schemas._planted", "mocapflow.pipeline"),
               (CORE_CONTRACT, "mocapflow.pipeline._planted", first.kernels or first.package),
               (PRESENTATION_CONTRACT, "mocapflow.presentation._planted", first.kernels or first.package),
               (FORMATS_CONTRACT, "mocapflow.formats._planted", first.kernels or first.package),
               (FORMATS_CONTRACT, "mocapflow.formats._planted_system", first.package),
               (SHARED_CONTRACT, f"{SHARED_KERNELS}._planted", first.kernels)]
    peers = [s for s in systems if s.name not in FLOORS]  # a floor is anyone's to import: plant a peer instead
    for i, system in enumerate(systems):
        others = [p for p in peers if p is not system]
        other = others[i % len(others)]
        planted.append((system_contract(system), f"{system.package}._planted", other.kernels or other.package))
        planted.append((system_contract(system), f"{system.package}._planted_system", other.package))
        if system.kernels:
            planted.append((system_contract(system), f"{system.kernels}._planted", other.kernels or other.package))
    return planted


def test_a_forbidden_import_planted_in_a_copy_breaks_its_contract(systems, tmp_path):
    config = contracts_config(systems)
    tree = tmp_path / "tree"
    for package in ROOT_PACKAGES:  # the Python files of the tree, as `mocapflow` (a namespace) in a folder
        source = Path(importlib.util.find_spec(package).submodule_search_locations[0])
        shutil.copytree(source, tree / Path(*package.split(".")), ignore=lambda folder, names: [
            n for n in names if n == "__pycache__" or (Path(folder, n).is_file() and not n.endswith(".py"))])

    clean = check_contracts(config, tmp_path, tree)
    assert all(origin.startswith(str(tree)) for origin in clean["origins"].values()), clean["origins"]
    assert all(c["kept"] for c in clean["contracts"].values()), broken(clean)

    planted = plants(systems)
    assert {contract for contract, _, _ in planted} == {c["name"] for c in config["contracts"]}
    for _, module, imported in planted:
        tree.joinpath(*module.split(".")).with_suffix(".py").write_text(f"import {imported}  # forbidden\n")
    result = check_contracts(config, tmp_path, tree)
    for contract, module, imported in planted:
        assert not result["contracts"][contract]["kept"], f"{contract}: kept with {module} importing {imported}"
        assert (module, imported) in result["contracts"][contract]["links"], (contract, module, imported, broken(result))


def task_home_problems(system: InRepoSystem) -> list[str]:
    """Where a task of ``system`` names a function outside its own kernels and the shared ones (a Lazy one also
    where its module does not import or lacks the name)."""
    homes = [f"mocapflow.tasks.{system.name}", SHARED_KERNELS]
    problems = []
    for spec in system.system.tasks if system.system else ():
        if spec.fn is None:
            continue
        if isinstance(spec.fn, registry.Lazy):
            module, where = spec.fn.module, f"Lazy({spec.fn.module!r}, {spec.fn.name!r})"
        else:
            module, where = spec.fn.__module__, f"{spec.fn.__module__}.{spec.fn.__qualname__}"
            homes_here = [*homes, system.package]  # a function defined in the system itself is its own
            if not any(within(module, h) for h in homes_here):
                problems.append(f"{system.name} task {spec.name!r}: {where} is not in {homes_here}")
            continue
        if not any(within(module, h) for h in homes):
            problems.append(f"{system.name} task {spec.name!r}: {where} is not in {homes}")
            continue
        try:
            found = getattr(importlib.import_module(module), spec.fn.name, None)
        except ImportError as exc:
            problems.append(f"{system.name} task {spec.name!r}: {where} does not import: {exc}")
            continue
        if not callable(found):
            problems.append(f"{system.name} task {spec.name!r}: {where}: {module} has no function {spec.fn.name!r}")
    return problems


def test_every_task_function_lives_in_its_own_systems_kernels(systems):
    lazy = [spec for s in systems if s.system for spec in s.system.tasks if isinstance(spec.fn, registry.Lazy)]
    assert lazy  # DeepMoCap's and the suit's keep torch out of planning
    problems = [p for s in systems for p in task_home_problems(s)]
    assert not problems, "\n".join(problems)


def test_a_task_naming_another_systems_kernels_is_found(systems):
    system = next(s for s in systems if s.system and s.system.tasks)
    other = next(s for s in systems if s is not system and s.kernels)
    spec = next(t for t in system.system.tasks if t.fn is not None)
    strays = [registry.Lazy(f"{other.kernels}.anything", "fn"), registry.Lazy(f"{system.kernels}.no_such_module", "fn"),
              registry.Lazy(SHARED_KERNELS + ".body", "no_such_function")]
    for stray in strays:
        swapped = dataclasses.replace(system, system=dataclasses.replace(system.system, tasks=(
            dataclasses.replace(spec, fn=stray),)))
        assert len(task_home_problems(swapped)) == 1, stray


if __name__ == "__main__":
    print(toml_section(contracts_config(in_repo_systems())), end="")

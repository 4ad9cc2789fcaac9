"""catalog.yaml: datasets, storage and stages, parsed once and validated with line numbers.

The catalog is the single place where a user swaps an implementation (``stages.flow.task``)
or changes a parameter. It is read with ``yaml.safe_load``; every error names the file, the
line, the dotted key, the bad value and the fix. ``--set dotted.key=value`` overrides any value.
"""

from __future__ import annotations

import copy
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping

import fsspec
import yaml

from mocapflow.pipeline import registry
from mocapflow.pipeline.errors import CatalogError
from mocapflow.schemas import ArtifactSchema, UnknownSchema, get_schema

TOP_KEYS = ("data_roots", "plugins", "storage", "datasets", "joint_take", "stages", "evaluation")
JOINT_TAKE_KEYS = ("datasets", "defaults", "sequences")
STORAGE_KEYS = ("root", "region_frames", "max_partition_bytes")

# Limits at the door, checked before anything is built from the catalog. A catalog is a few kilobytes of hand-written
# YAML: the size and alias limits refuse an alias bomb (each level repeating the one below) before it is expanded.
MAX_CATALOG_BYTES = 1 << 20
MAX_ALIASES = 1000
MAX_EXPANDED_NODES = 100_000  # nodes of the document with every alias expanded
# What a dataset may state (studio ``defaults`` / ``sequences`` fields, a markers ``count``): far above any real take
# (a million frames is nine hours at 30 fps), far below what exhausts a worker.
COUNT_LIMITS = {"frames": 1_000_000, "views": 64, "width": 16384, "height": 16384, "count": 100_000,
                "markers": 100_000}
DEFAULT_MAX_PARTITION_BYTES = 64 << 30  # storage.max_partition_bytes: what one partition may allocate (plan.py)
STAGE_KEYS = ("task", "params", "inputs", "dataset", "region_frames")
DEFAULT_REGION_FRAMES = 32


@dataclass(frozen=True)
class DatasetConfig:
    """Where raw sequences come from. ``options``' keys are the ones the reader of ``kind`` names in its
    ``options`` (checked when the catalog is loaded); their values are checked by that reader."""

    name: str
    kind: str
    options: Mapping[str, Any]
    where: str
    lines: Mapping[tuple, Any] = field(default_factory=dict, compare=False, repr=False)  # option keys -> line

    def where_of(self, *keys) -> str:
        """Where an option (``where_of("sequences", "walk", "motion")``) is in the catalog: the line of the deepest
        of ``keys`` the catalog holds (``--set`` where an override set it), else the dataset's."""
        path = ".".join(str(k) for k in keys)
        for n in range(len(keys), 0, -1):
            line = self.lines.get(tuple(keys[:n]))
            if line is not None:
                at = f"line {line}" if isinstance(line, int) else line
                return f"{self.where.split(' (', 1)[0]} ({at}): datasets.{self.name}.{path}"
        return f"{self.where}.{path}"


@dataclass(frozen=True)
class StageConfig:
    """One stage, resolved once at load: its implementation, its output schema and its checked params."""

    name: str
    spec: registry.TaskSpec  # the registered implementation
    schema: ArtifactSchema  # of its output
    params: Any  # the task's frozen params dataclass
    inputs: Mapping[str, str]  # role -> upstream stage name
    dataset: str | None
    region_frames: int

    @property
    def task(self) -> str:
        return self.spec.name


@dataclass(frozen=True)
class JointTake:
    """One performance filmed by several datasets at once (``joint_take:``): every take (a studio sequence: subject,
    motion, seed) is a sequence of each dataset, ``<take>.<dataset>``, made from the same posed mesh; each dataset
    films it its own way (its kind, its ``defaults``) and its own stages run on it."""

    datasets: tuple[str, ...]
    takes: tuple[str, ...]

    def sequence(self, take: str, dataset: str) -> str:
        return f"{take}.{dataset}"


@dataclass(frozen=True)
class Catalog:
    path: Path
    root: str
    data_roots: tuple[Path, ...]
    plugins: tuple[str, ...]
    datasets: Mapping[str, DatasetConfig]
    stages: Mapping[str, StageConfig]  # in topological order
    evaluation: Mapping[str, Any] = field(default_factory=dict)
    max_partition_bytes: int = DEFAULT_MAX_PARTITION_BYTES
    joint_take: JointTake | None = None

    def ancestors(self, stage: str) -> list[str]:
        """``stage`` and everything it depends on, in topological order."""
        need, todo = set(), [stage]
        while todo:
            name = todo.pop()
            if name not in need:
                need.add(name)
                todo.extend(self.stages[name].inputs.values())
        return [s for s in self.stages if s in need]

    def resolve_data_path(self, value: str, where: str) -> Path:
        """A dataset path, relative to the catalog; it must stay inside one of ``data_roots``."""
        path = (self.path.parent / os.path.expanduser(value)).resolve()
        if not any(path == root or root in path.parents for root in self.data_roots):
            roots = ", ".join(str(r) for r in self.data_roots)
            raise CatalogError(f"{where}: path {value!r} resolves to {path}, outside the declared data_roots ({roots}); "
                               "add its folder to data_roots or move the data")
        return path


def load_catalog(path: str | os.PathLike, overrides: tuple[str, ...] = ()) -> Catalog:
    """Parse, override (``dotted.key=value``) and validate a catalog file."""
    path = Path(path).resolve()
    try:
        text = path.read_bytes().decode("utf-8")
    except OSError as exc:
        raise CatalogError(f"cannot read catalog {path}: {exc.strerror}; pass --catalog PATH") from exc
    except UnicodeDecodeError as exc:
        line = path.read_bytes()[:exc.start].count(b"\n") + 1
        raise CatalogError(f"{path} (line {line}): byte {exc.start} is not UTF-8 text; a catalog is UTF-8 YAML: fix or "
                           "remove the damaged characters") from exc
    try:
        check_document(text, path)
        data = yaml.safe_load(text) or {}
        lines = _line_index(yaml.compose(text, Loader=yaml.SafeLoader))
    except yaml.YAMLError as exc:
        raise CatalogError(f"{path}: not valid YAML: {exc}") from exc
    if not isinstance(data, dict):
        raise CatalogError(f"{path}: the catalog must be a mapping with keys {list(TOP_KEYS)}")
    data = apply_overrides(data, overrides, lines)
    return _Validator(path, lines).catalog(data)


def check_document(text: str, path: Path) -> None:
    """CatalogError unless ``text`` is within the document limits: its size, its aliases and the size of the
    document with every alias expanded (counted from the parser's events, without expanding anything)."""
    if len(text.encode()) > MAX_CATALOG_BYTES:
        raise CatalogError(f"{path} (line {text.count(chr(10)) + 1}): the catalog is {len(text.encode())} bytes, over "
                           f"the limit of {MAX_CATALOG_BYTES} bytes; a catalog names data, it does not hold it: move "
                           "the values into files it names")
    sizes: dict[str, int] = {}  # anchor -> nodes of its value, aliases expanded
    stack: list[list] = []  # open collections: [anchor, nodes so far]
    aliases = expanded = 0
    for event in yaml.parse(text, Loader=yaml.SafeLoader):
        if isinstance(event, yaml.AliasEvent):
            aliases += 1
            nodes = sizes.get(event.anchor, 1)
            expanded += nodes
            if aliases > MAX_ALIASES or expanded > MAX_EXPANDED_NODES:
                what = (f"{aliases} aliases, over the limit of {MAX_ALIASES}" if aliases > MAX_ALIASES else
                        f"alias *{event.anchor} makes the expanded document over {MAX_EXPANDED_NODES} values (the "
                        f"limit; this alias alone is {nodes})")
                raise CatalogError(f"{path} (line {event.start_mark.line + 1}): {what}; write the values out, or use "
                                   "fewer nested aliases")
        elif isinstance(event, (yaml.MappingStartEvent, yaml.SequenceStartEvent)):
            stack.append([event.anchor, 1])
            continue
        elif isinstance(event, (yaml.MappingEndEvent, yaml.SequenceEndEvent)):
            anchor, nodes = stack.pop()
            if anchor:
                sizes[anchor] = nodes
        elif isinstance(event, yaml.ScalarEvent):
            nodes = 1
            if event.anchor:
                sizes[event.anchor] = 1
        else:
            continue
        if stack:
            stack[-1][1] += nodes


def apply_overrides(data: dict, overrides: tuple[str, ...], lines: dict) -> dict:
    data = copy.deepcopy(data)
    for item in overrides:
        dotted, sep, raw = item.partition("=")
        if not sep or not dotted:
            raise CatalogError(f"--set {item!r}: expected dotted.key=value, e.g. --set stages.flow.task=dis")
        keys = dotted.split(".")
        node = data
        for key in keys[:-1]:
            child = node.setdefault(key, {})
            if not isinstance(child, dict):
                raise CatalogError(f"--set {item!r}: {key!r} is a {type(child).__name__}, not a mapping")
            node = child
        node[keys[-1]] = yaml.safe_load(raw) if raw else ""
        lines[tuple(keys)] = "--set"
    return data


def _line_index(node, prefix=()) -> dict[tuple, int | str]:
    """Map each dotted key path to its 1-based line in the YAML text."""
    out: dict[tuple, int | str] = {}
    if isinstance(node, yaml.MappingNode):
        for key_node, value_node in node.value:
            path = prefix + (key_node.value,)
            out[path] = key_node.start_mark.line + 1
            out.update(_line_index(value_node, path))
    elif isinstance(node, yaml.SequenceNode):
        for i, item in enumerate(node.value):
            out[prefix + (i,)] = item.start_mark.line + 1
            out.update(_line_index(item, prefix + (i,)))
    return out


class _Validator:
    def __init__(self, path: Path, lines: dict):
        self.path = path
        self.lines = lines

    def where(self, *keys) -> str:
        line = None
        for n in range(len(keys), 0, -1):
            line = self.lines.get(tuple(keys[:n]))
            if line is not None:
                break
        at = f"line {line}" if isinstance(line, int) else (line or "?")
        return f"{self.path.name} ({at}): {'.'.join(str(k) for k in keys)}"

    def mapping(self, value, *keys) -> dict:
        if value is None:
            return {}
        if not isinstance(value, dict):
            raise CatalogError(f"{self.where(*keys)}: expected a mapping, got {type(value).__name__} {value!r}")
        unnamed = [key for key in value if isinstance(key, bool) or key is None]
        if unnamed:  # YAML 1.1 reads on/off/yes/no/true/false as booleans and ~ or null as nothing
            raise CatalogError(f"{self.where(*keys)}: key {unnamed[0]!r} is not a name (YAML reads on, off, yes, "
                               "no, true, false as booleans and null or ~ as nothing); quote it, e.g. 'on':")
        return value

    def known_keys(self, value: dict, allowed, *keys) -> None:
        for key in value:
            if key not in allowed:
                raise CatalogError(f"{self.where(*keys, key)}: unknown key {key!r}"
                                   f"{registry.did_you_mean(str(key), allowed)}; allowed: {list(allowed)}")

    def catalog(self, data: dict) -> Catalog:
        self.known_keys(data, TOP_KEYS)
        plugins = tuple(data.get("plugins") or ())
        registry.import_plugins(plugins)
        storage = self.mapping(data.get("storage"), "storage")
        self.known_keys(storage, STORAGE_KEYS, "storage")
        root = self.storage_root(str(storage.get("root", "storage/")))
        region = storage.get("region_frames", DEFAULT_REGION_FRAMES)
        self.positive_int(region, "storage", "region_frames")
        ceiling = self.positive_int(storage.get("max_partition_bytes", DEFAULT_MAX_PARTITION_BYTES), "storage",
                                    "max_partition_bytes")
        roots = data.get("data_roots") or ["."]
        if not isinstance(roots, list):
            raise CatalogError(f"{self.where('data_roots')}: expected a list of folders, got {roots!r}")
        data_roots = tuple((self.path.parent / os.path.expanduser(str(r))).resolve() for r in roots)
        raw_datasets = self.mapping(data.get("datasets"), "datasets")
        joint = None
        if data.get("joint_take") is not None:
            raw_datasets, joint = self.joint_take(self.mapping(data["joint_take"], "joint_take"), raw_datasets)
        datasets = self.datasets(raw_datasets)
        stages = self.stages(self.mapping(data.get("stages"), "stages"), datasets, region)
        evaluation = self.mapping(data.get("evaluation"), "evaluation")
        return Catalog(self.path, root, data_roots, plugins, datasets, stages, evaluation, ceiling, joint)

    def joint_take(self, raw: dict, datasets: dict) -> tuple[dict, JointTake]:
        """The datasets with the joint take's sequences given to each it names (``<take>.<dataset>``; the joint
        ``defaults`` under each dataset's own), and the JointTake."""
        self.known_keys(raw, JOINT_TAKE_KEYS, "joint_take")
        names = raw.get("datasets")
        if not isinstance(names, list) or not names:
            raise CatalogError(f"{self.where('joint_take', 'datasets')}: expected a list of the datasets that film the "
                               f"joint take (one per system), e.g. [dmc, uuo, suit]; got {names!r}")
        takes = self.mapping(raw.get("sequences"), "joint_take", "sequences")
        if not takes:
            raise CatalogError(f"{self.where('joint_take')}: a joint take needs 'sequences: {{id: {{motion: ..., "
                               "seed: ...}}}}', the performances every dataset films")
        kinds = registry.dataset_kinds()
        out = dict(datasets)
        for name in names:
            if name not in datasets:
                raise CatalogError(f"{self.where('joint_take', 'datasets')}: no dataset {name!r}"
                                   f"{registry.did_you_mean(str(name), datasets)}; declare it under datasets:")
            body = dict(self.mapping(datasets[name], "datasets", name))
            options = getattr(kinds.get(body.get("kind")), "options", None) or ()
            if "sequences" not in options or "defaults" not in options:
                raise CatalogError(f"{self.where('datasets', name, 'kind')}: a {body.get('kind')!r} dataset cannot "
                                   "film a joint take (it takes no sequences and defaults); use a studio kind")
            if body.get("sequences"):
                raise CatalogError(f"{self.where('datasets', name, 'sequences')}: dataset {name!r} films the joint "
                                   "take; its sequences are the joint take's, so leave its own out")
            body["defaults"] = {**self.mapping(raw.get("defaults"), "joint_take", "defaults"),
                                **self.mapping(body.get("defaults"), "datasets", name, "defaults")}
            body["sequences"] = {f"{take}.{name}": copy.deepcopy(fields) for take, fields in takes.items()}
            for key, line in list(self.lines.items()):  # errors in a take's fields name the joint take's line
                if key[:2] == ("joint_take", "sequences") and len(key) > 2:
                    self.lines[("datasets", name, "sequences", f"{key[2]}.{name}", *key[3:])] = line
            out[name] = body
        return out, JointTake(tuple(str(n) for n in names), tuple(str(t) for t in takes))

    def storage_root(self, root: str) -> str:
        """The storage root: a local folder (resolved against the catalog; not a file) or a URL of a filesystem
        fsspec can open here."""
        if "://" in root:
            protocol = root.split("://", 1)[0]
            try:
                fsspec.get_filesystem_class(protocol)
            except (ValueError, ImportError) as exc:
                raise CatalogError(f"{self.where('storage', 'root')}: cannot store artifacts at {root!r}: {exc}; use a "
                                   "folder or the URL of an installed fsspec filesystem (e.g. s3:// with s3fs)") from exc
            return root
        path = (self.path.parent / root).resolve()
        existing = next(p for p in (path, *path.parents) if p.exists())
        if not existing.is_dir():
            raise CatalogError(f"{self.where('storage', 'root')}: {root!r} resolves to {path}, but {existing} is a file; "
                               "point storage.root at a folder")
        return str(path)

    def positive_int(self, value, *keys) -> int:
        if isinstance(value, bool) or not isinstance(value, int) or value <= 0:
            raise CatalogError(f"{self.where(*keys)}: expected a positive integer, got {value!r}")
        return value

    def datasets(self, raw: dict) -> dict[str, DatasetConfig]:
        kinds = registry.dataset_kinds()
        out = {}
        for name, body in raw.items():
            body = dict(self.mapping(body, "datasets", name))
            kind = body.pop("kind", None)
            if kind not in kinds:
                raise CatalogError(f"{self.where('datasets', name, 'kind')}: unknown dataset kind {kind!r}"
                                   f"{registry.did_you_mean(str(kind), kinds)}; use one of {sorted(kinds)}")
            options = getattr(kinds[kind], "options", None)  # a plugin's reader may leave its own unchecked
            for key in body if options is not None else ():
                if key not in options:
                    raise CatalogError(f"{self.where('datasets', name, key)}: unknown option {key!r} for a {kind!r} "
                                       f"dataset{registry.did_you_mean(str(key), options)}; its options are "
                                       f"{['kind', *options]}")
            self.counts(body, "datasets", name)
            own = {key[2:]: line for key, line in self.lines.items() if key[:2] == ("datasets", name) and len(key) > 2}
            out[name] = DatasetConfig(name, kind, body, self.where("datasets", name), own)
        return out

    def counts(self, value, *keys) -> None:
        """Every count a dataset states (``COUNT_LIMITS``' keys, at any depth: studio ``defaults`` and ``sequences``,
        a markers ``count``) within its limit."""
        if isinstance(value, dict):
            for key, child in value.items():
                limit = COUNT_LIMITS.get(str(key))
                if limit is not None and isinstance(child, (int, float)) and not isinstance(child, bool) \
                        and child > limit:
                    raise CatalogError(f"{self.where(*keys, key)}: {key}={child!r} is over the limit of {limit}; "
                                       f"split the take into shorter sequences, or lower {key}")
                self.counts(child, *keys, key)
        elif isinstance(value, list):
            for n, child in enumerate(value):
                self.counts(child, *keys, n)

    def stages(self, raw: dict, datasets: dict, default_region: int) -> dict[str, StageConfig]:
        parsed: dict[str, StageConfig] = {}
        for name, body in raw.items():
            body = self.mapping(body, "stages", name)
            self.known_keys(body, STAGE_KEYS, "stages", name)
            if "task" not in body:
                raise CatalogError(f"{self.where('stages', name)}: stage {name!r} has no 'task'; "
                                   f"name a registered implementation, one of {registry.names()}")
            try:
                spec = registry.get(str(body["task"]))
            except CatalogError as exc:
                raise CatalogError(f"{self.where('stages', name, 'task')}: {exc}") from None
            self.check_schemas(name, spec)
            unnamed = [key for key in self.mapping(body.get("params"), "stages", name, "params")
                       if not isinstance(key, str)]
            if unnamed:
                raise CatalogError(f"{self.where('stages', name, 'params', unnamed[0])}: parameter name {unnamed[0]!r} is "
                                   "not a name; parameters are named by words (quote it if it must be a number)")
            params = registry.build_params(spec, self.mapping(body.get("params"), "stages", name, "params"),
                                           lambda key, name=name: self.where("stages", name, "params", key))
            inputs = self.inputs(name, spec, body.get("inputs"))
            dataset = self.dataset_ref(name, spec, body.get("dataset"), datasets)
            region = self.positive_int(body.get("region_frames", default_region), "stages", name, "region_frames")
            parsed[name] = StageConfig(name, spec, get_schema(spec.output), params, inputs, dataset, region)
        self.check_inputs(parsed)
        return {name: parsed[name] for name in self.topological(parsed)}

    def inputs(self, stage: str, spec: registry.TaskSpec, raw) -> dict[str, str]:
        if raw is None:
            raw = {}
        if isinstance(raw, list):  # positional: the task's roles in declared order
            if len(raw) != len(spec.inputs):
                raise CatalogError(f"{self.where('stages', stage, 'inputs')}: task {spec.name!r} takes "
                                   f"{len(spec.inputs)} input(s) {list(spec.inputs)}, got {raw!r}")
            raw = dict(zip(spec.inputs, (str(s) for s in raw)))
        raw = self.mapping(raw, "stages", stage, "inputs")
        for role in raw:
            if role not in spec.inputs:
                raise CatalogError(f"{self.where('stages', stage, 'inputs')}: task {spec.name!r} takes no input "
                                   f"{role!r}{registry.did_you_mean(str(role), spec.inputs)}; it takes {list(spec.inputs)}")
        for role in spec.inputs:
            if role not in raw:
                raise CatalogError(f"{self.where('stages', stage, 'inputs')}: task {spec.name!r} needs input {role!r} "
                                   f"(an artifact of schema {spec.inputs[role]!r}); add it to stages.{stage}.inputs")
        return {str(k): str(v) for k, v in raw.items()}

    def dataset_ref(self, stage: str, spec: registry.TaskSpec, raw, datasets: dict) -> str | None:
        if not spec.source:
            if raw is not None:
                raise CatalogError(f"{self.where('stages', stage, 'dataset')}: only source tasks read a dataset; "
                                   f"task {spec.name!r} reads stage outputs through 'inputs'")
            return None
        if raw is None and len(datasets) == 1:
            return next(iter(datasets))
        if raw not in datasets:
            raise CatalogError(f"{self.where('stages', stage, 'dataset')}: unknown dataset {raw!r}"
                               f"{registry.did_you_mean(str(raw), datasets)}; declared: {sorted(datasets)}")
        return str(raw)

    def check_schemas(self, stage: str, spec: registry.TaskSpec) -> None:
        """Every schema the stage's task writes or reads is registered (the engine looks each up by name)."""
        named = [("writes its output as", spec.output)] + [(f"reads input {role!r} as", s) for role, s in spec.inputs.items()]
        for what, schema in named:
            try:
                get_schema(schema)
            except UnknownSchema as exc:
                raise CatalogError(f"{self.where('stages', stage, 'task')}: task {spec.name!r} {what} schema {schema!r}, "
                                   f"which is not registered: {exc}; or choose another task") from exc

    def check_inputs(self, stages: dict[str, StageConfig]) -> None:
        for name, stage in stages.items():
            spec = stage.spec
            for role, upstream in stage.inputs.items():
                where = self.where("stages", name, "inputs")
                if upstream not in stages:
                    raise CatalogError(f"{where}: input {role!r} names stage {upstream!r}, which is not declared"
                                       f"{registry.did_you_mean(upstream, stages)}; declared stages: {list(stages)}")
                produced = stages[upstream].spec.output
                expected = get_schema(spec.inputs[role]).name
                if produced != expected:
                    raise CatalogError(f"{where}: input {role!r} of task {spec.name!r} must be a {expected!r} artifact, "
                                       f"but stage {upstream!r} ({stages[upstream].task}) writes {produced!r}")

    def topological(self, stages: dict[str, StageConfig]) -> list[str]:
        order: list[str] = []
        state: dict[str, str] = {}

        def visit(name: str, path: list[str]) -> None:
            if state.get(name) == "done":
                return
            if state.get(name) == "active":
                cycle = path[path.index(name):] + [name]
                raise CatalogError(f"{self.where('stages', name)}: stages form a cycle: {' -> '.join(cycle)}; "
                                   "remove one of these inputs")
            state[name] = "active"
            for upstream in stages[name].inputs.values():
                visit(upstream, path + [name])
            state[name] = "done"
            order.append(name)

        for name in stages:
            visit(name, [])
        return order


def stage_writing(catalog, schema: str, *, refined: bool = False) -> str | None:
    """The last stage of the catalog whose implementation writes ``schema``: one that also reads that schema
    (refines an upstream artifact of its kind, as refine_reflectors does the views' reflectors2d) when
    ``refined``, otherwise one that does not."""
    found = [s.name for s in catalog.stages.values() if s.spec.output == schema
             and (schema in s.spec.inputs.values()) == refined]
    return found[-1] if found else None


def final_stage(catalog, schema: str) -> str | None:
    """The stage whose ``schema`` artifact is the one to hand out (exported, reported): the last stage refining
    an artifact of that schema (as the plausibility check does the smoothed markers) where there is one, otherwise
    the last stage writing it."""
    return stage_writing(catalog, schema, refined=True) or stage_writing(catalog, schema)

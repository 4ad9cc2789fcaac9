"""The one registry of the engine: capture systems, their task implementations, dataset kinds, schemas,
evaluators, exporters, report sections and weight readers.

The engine knows no system. A system (DeepMoCap, UUO, the checkerboard suit, the markerless peer, or a user's plug-in) is a
:class:`System` value that declares everything it adds; it reaches the engine through one path, whichever way it
is found: an entry point of the group ``mocapflow.systems`` (how the built-in systems are found, as xarray finds
its backends) or a module named in a catalog's ``plugins:`` that calls :func:`register_system` on import. Either
way :func:`register_system` registers its parts here, and `mocapflow evaluate`, `export`, `report` and `train`
dispatch through these tables, never on a schema's or a system's name.

A task (:class:`TaskSpec`) says how the engine drives one pure function of tasks/: which stage partition kind it
runs on, which artifacts it reads (role -> schema) and writes, its frozen params dataclass, its explicit code
version (bump it when results change), the frame halo it needs around a region, and which params name weight
files (hashed into the cache key; an empty one means the file shipped in mocapflow.models).
"""

from __future__ import annotations

import dataclasses
import difflib
import importlib
import inspect
import re
import types
import typing
from dataclasses import dataclass, field
from importlib.metadata import entry_points
from typing import Any, Callable, Literal, Mapping, Protocol

from mocapflow.pipeline.errors import CatalogError
from mocapflow.schemas import ArtifactSchema, register_schema

ENTRY_POINT_GROUP = "mocapflow.systems"

Partitioning = Literal["view", "sequence", "dataset"]


@dataclass(frozen=True)
class TaskSpec:
    """How the engine runs one implementation.

    ``fn(**inputs, config=params, **weights) -> xr.Dataset`` for ordinary tasks: each input is the
    upstream artifact sliced to this partition and the region's frames (plus the halo), ``config`` the
    stage's frozen params dataclass, and each of ``weights_params`` the tensors of the weight file that
    parameter names (loaded by the engine). :func:`register` checks ``fn``'s signature against that.
    Source tasks (``source=True``) are run by the dataset reader instead and have no inputs.
    ``reads`` names the variables a role needs (all when absent), so large unused arrays such as
    ground truth are never loaded. Parameters whose field carries ``metadata={"runtime": True}`` (how a
    task runs, not what it computes: a batch size, a device, worker processes) stay out of cache keys.

    A per-dataset task (a training) may declare ``streams`` (role -> its large variables): that input then
    arrives as ``tasks.shared.samples.Samples``, the large variables read one sample at a time, so the set need
    not fit in memory. With ``checkpoints`` it also takes ``checkpoint`` (``load() -> dict | None``,
    ``save(dict)``): state it saves survives a killed run, and the next run of the same partition (same cache
    key) gets it back; the engine drops it once the partition is committed.
    """

    name: str
    fn: Callable[..., Any] | None
    version: str
    params: type
    output: str
    partition: Partitioning
    inputs: Mapping[str, str] = field(default_factory=dict)
    halo: tuple[int, int] = (0, 0)
    whole_sequence: bool = False  # the task needs every frame at once (temporal filters): one region
    reads: Mapping[str, tuple[str, ...]] = field(default_factory=dict)  # role -> the variables it needs
    weights_params: tuple[str, ...] = ()
    packaged_weights: Mapping[str, str] = field(default_factory=dict)  # param -> file in mocapflow.models, when empty
    streams: Mapping[str, tuple[str, ...]] = field(default_factory=dict)  # role -> variables read per sample
    checkpoints: bool = False  # the task takes ``checkpoint`` (per-dataset tasks only)
    source: bool = False
    description: str = ""


@dataclass(frozen=True)
class Lazy:
    """A task function imported on first call (keeps heavy modules such as torch out of planning); its
    signature is checked then (and by the tests, which import every built-in task)."""

    module: str
    name: str
    roles: tuple[str, ...] = ()  # the parameters it must take, set by register()

    def resolve(self) -> Callable[..., Any]:
        fn = getattr(importlib.import_module(self.module), self.name)
        check_signature(f"{self.module}.{self.name}", fn, self.roles)
        return fn

    def __call__(self, *args, **kwargs):
        return self.resolve()(*args, **kwargs)


@dataclass(frozen=True)
class NoParams:
    """Params of a task that takes none."""


class DatasetKind(Protocol):
    """A dataset reader: ``options`` (the catalog keys a dataset of this kind takes besides ``kind``),
    ``has_views`` (whether a sequence is filmed by named sensors), ``discover(catalog, dataset) ->
    [SequenceInfo]`` on the driver and ``read(dataset, seq, start, stop) -> xr.Dataset`` on a worker."""

    options: tuple[str, ...]

    def discover(self, catalog, dataset) -> list: ...

    def read(self, dataset, seq, start: int, stop: int) -> Any: ...


@dataclass(frozen=True)
class Evaluator:
    """What `mocapflow evaluate` scores for one system. ``applies(catalog)``: whether the catalog has stages this
    evaluator scores; ``evaluate(catalog, plan, store, per_sequence, thorough)`` returns figures (a dict merged into
    the evaluation's result; its per-sequence figures go into ``per_sequence[seq_id]``; ``thorough`` False skips
    figures that are slow and no figure of the capture itself); ``headline(result)`` the flat JSON figures and
    ``table(result)`` the text lines it prints (both given the whole result)."""

    name: str
    applies: Callable[[Any], bool]
    evaluate: Callable[..., dict]
    headline: Callable[[dict], dict]
    table: Callable[[dict], list[str]]


@dataclass(frozen=True)
class ExportJob:
    """One sequence to export: the stage's artifact (``data``) and what an exporter may read besides it."""

    catalog: Any
    plan: Any
    store: Any
    stage: str
    sequence: str
    data: Any  # xr.Dataset of the stage for this sequence
    out_dir: Any  # pathlib.Path
    up: str | None = None  # TRC's up axis, where the format has one


@dataclass(frozen=True)
class Exporter:
    """A file format one system writes: ``format`` (the --format name), the ``schemas`` it exports (in order of
    preference when no --stage is named), ``write(job) -> [Path]`` per sequence, optionally ``default_stage(catalog)``
    (else the last stage writing one of ``schemas``) and ``needs(catalog, stage)``, further stages computed first."""

    format: str
    schemas: tuple[str, ...]
    write: Callable[[ExportJob], list]
    default_stage: Callable[[Any], str | None] | None = None
    needs: Callable[[Any, str], list[str]] | None = None
    options: tuple[str, ...] = ()  # the export options it takes ("up")


@dataclass(frozen=True)
class ReportSection:
    """What `mocapflow report` shows of one system. ``applies(catalog)``; ``takes(catalog, plan, store)`` the
    sequences as the report's :class:`~mocapflow.presentation.report.Take` (markers, joints, truth) or [];
    ``figures(folder, catalog, plan, store, result)`` extra images (paths) given the evaluation's result (``{}``
    where the take has no ground truth to evaluate against: draw what needs none);
    ``named_figures``: the evaluation's JSON keys it names on the page, key -> (label, scale, unit);
    ``truth``: the variable of a recording (the catalog's source stage) that holds the system's ground truth, where
    its recordings may carry one (the studio's takes do): with it in every sequence, the page says what an evaluation
    against it found, or why none was made."""

    name: str
    applies: Callable[[Any], bool]
    takes: Callable[..., list] | None = None
    figures: Callable[..., list] | None = None
    named_figures: Mapping[str, tuple[str, float, str]] = field(default_factory=dict)
    truth: str | None = None


@dataclass(frozen=True)
class Skeleton:
    """The joints a capture gives, as the system declares them: their names, each one's parent (-1 at a root) and
    the body parts `mocapflow compare` reports its error by (part -> joint names)."""

    names: tuple[str, ...]
    parents: tuple[int, ...]
    parts: Mapping[str, tuple[str, ...]]

    def __post_init__(self):
        unknown = sorted({j for joints in self.parts.values() for j in joints} - set(self.names))
        if len(self.parents) != len(self.names) or unknown:
            raise CatalogError(f"a skeleton of {len(self.names)} joints has {len(self.parents)} parents and parts "
                               f"naming joints it lacks ({unknown}); declare one parent per joint and parts of its "
                               "own joints")

    def part_index(self) -> dict[str, list[int]]:
        """Per part the indices of its joints."""
        return {part: [self.names.index(j) for j in joints] for part, joints in self.parts.items()}


@dataclass(frozen=True)
class Capture:
    """One system's capture of one sequence, as `mocapflow compare` scores it: its joints per frame (``skeleton``
    names them), the studio's truth of the same joints and frames, and the surface where the system gives one.
    Frames are the sequence's own; ``fps`` puts them on the take's clock (frame / fps)."""

    stage: str  # the stage whose output is compared
    fps: float
    joints: Any  # (frame, joint, 3) m, NaN where the system gives none
    truth: Any  # (frame, joint, 3) m, the studio's
    skeleton: Skeleton = field(kw_only=True)  # the joints' names, tree and parts, as the system declares them
    surface_error_mm: Any = None  # (frame,) median distance of the surface given from the true skin, or None
    surface: Any = None  # (frame, point, 3) m, a few points of the surface for the 3D view, or None
    needs: Mapping[str, str] = field(default_factory=dict)  # what the capture needs: cameras, markers, a prior


@dataclass(frozen=True)
class Comparer:
    """How `mocapflow compare` reads one system. ``stage(catalog, stages)``: of a dataset's stages (topological
    order), the one whose output it compares, or None; ``capture(catalog, plan, store, stage, sequence)`` ->
    :class:`Capture`; ``requirements``: a line on what the system needs, whatever the take."""

    system: str
    stage: Callable[[Any, list], str | None]
    capture: Callable[..., Capture]
    requirements: str = ""


@dataclass(frozen=True)
class Command:
    """A command a system adds to the ``mocapflow`` command line: the click command ``name`` of ``module``,
    imported only when the command line lists or runs it (so planning never imports it)."""

    module: str
    name: str

    def load(self) -> Any:
        try:
            command = getattr(importlib.import_module(self.module), self.name)
        except (ImportError, AttributeError) as exc:
            raise CatalogError(f"command {self.module}:{self.name} cannot be loaded ({exc}); fix the system's "
                               "commands declaration") from exc
        return command


@dataclass(frozen=True)
class System:
    """Everything one capture system (or source of data) adds to the engine, declared in one place."""

    name: str
    description: str = ""
    tasks: tuple[TaskSpec, ...] = ()
    dataset_kinds: Mapping[str, Any] = field(default_factory=dict)  # kind -> DatasetKind
    schemas: tuple[ArtifactSchema, ...] = ()
    evaluators: tuple[Evaluator, ...] = ()
    exporters: tuple[Exporter, ...] = ()
    report: tuple[ReportSection, ...] = ()
    weights: Mapping[str, Callable[[Any], dict]] = field(default_factory=dict)  # schema -> tensors of its artifact
    compare: Comparer | None = None  # how `mocapflow compare` reads its captures
    commands: Mapping[str, Command] = field(default_factory=dict)  # name -> a command it adds to `mocapflow`


_REGISTRY: dict[str, TaskSpec] = {}
_SYSTEMS: dict[str, System] = {}
_DATASET_KINDS: dict[str, Any] = {}
_BUILTINS_LOADED = False


def register(spec: TaskSpec) -> TaskSpec:
    """Register (or replace) an implementation under ``spec.name``, after checking that its function takes
    exactly its input roles, ``config`` and its weight parameters (a Lazy function: when first imported)."""
    if not dataclasses.is_dataclass(spec.params):
        raise CatalogError(f"task {spec.name!r}: params must be a frozen dataclass, got {spec.params!r}")
    if not spec.params.__dataclass_params__.frozen:
        raise CatalogError(f"task {spec.name!r}: params {spec.params.__name__} must be frozen "
                           "(@dataclass(frozen=True)): a stage's config never changes under a worker")
    if (spec.streams or spec.checkpoints) and spec.partition != "dataset":
        raise CatalogError(f"task {spec.name!r} is partitioned per {spec.partition!r} but declares "
                           f"{'streams' if spec.streams else 'checkpoints'}, which only a per-dataset task (a training) "
                           "may; drop them or partition it per dataset")
    roles = task_parameters(spec)
    if isinstance(spec.fn, Lazy):
        spec = dataclasses.replace(spec, fn=dataclasses.replace(spec.fn, roles=roles))
    elif spec.fn is not None:
        check_signature(f"task {spec.name!r}", spec.fn, roles)
    _REGISTRY[spec.name] = spec
    return spec


def task_parameters(spec: TaskSpec) -> tuple[str, ...]:
    """The parameters a task's function takes, in order: its input roles, ``config``, its weight parameters,
    ``checkpoint`` where it keeps one."""
    return (*spec.inputs, "config", *spec.weights_params, *(("checkpoint",) if spec.checkpoints else ()))


def check_signature(what: str, fn: Callable[..., Any], roles: tuple[str, ...]) -> None:
    """Raise CatalogError unless ``fn`` takes exactly the parameters ``roles`` (each by keyword)."""
    try:
        params = inspect.signature(fn).parameters
    except (TypeError, ValueError) as exc:
        raise CatalogError(f"{what}: its function {fn!r} has no inspectable signature ({exc})") from exc
    takes = [name for name, p in params.items() if p.kind in (p.POSITIONAL_OR_KEYWORD, p.KEYWORD_ONLY)]
    loose = [name for name, p in params.items() if p.kind in (p.VAR_POSITIONAL, p.VAR_KEYWORD, p.POSITIONAL_ONLY)]
    if loose or sorted(takes) != sorted(roles):
        raise CatalogError(f"{what}: its function takes ({', '.join(params)}) but the engine calls it with "
                           f"({', '.join(roles)}): its declared inputs, then config, then its weight parameters; "
                           "make the two agree")


def runtime_fields(params: type) -> tuple[str, ...]:
    """The fields of a params dataclass marked ``metadata={"runtime": True}`` (kept out of cache keys)."""
    return tuple(f.name for f in dataclasses.fields(params) if f.metadata.get("runtime"))


def get(name: str) -> TaskSpec:
    _load_builtins()
    try:
        return _REGISTRY[name]
    except KeyError:
        raise CatalogError(f"unknown task {name!r}{did_you_mean(name, _REGISTRY)}; registered: {sorted(_REGISTRY)}") from None


def names() -> list[str]:
    _load_builtins()
    return sorted(_REGISTRY)


def register_system(system: System) -> System:
    """Register (or replace) a system and every part it declares; returns it for module-level use."""
    if not isinstance(system, System):
        raise CatalogError(f"a system must be a mocapflow.pipeline.registry.System, got {system!r}; declare one "
                           "(see docs/adding-a-system.md)")
    for kind, reader in system.dataset_kinds.items():
        owner = next((s.name for s in _SYSTEMS.values() if kind in s.dataset_kinds and s.name != system.name), None)
        if owner is not None:
            raise CatalogError(f"system {system.name!r} declares dataset kind {kind!r}, which system {owner!r} "
                               "already declares; give it another name")
        _DATASET_KINDS[kind] = reader
    for schema in system.schemas:
        register_schema(schema)
    for spec in system.tasks:
        register(spec)
    _SYSTEMS[system.name] = system
    return system


def commands() -> dict[str, tuple[str, Command]]:
    """Every command the registered systems add: name -> (system, command); a name two systems add is refused."""
    found: dict[str, tuple[str, Command]] = {}
    for system in systems():
        for name, command in system.commands.items():
            if name in found:
                raise CatalogError(f"systems {found[name][0]!r} and {system.name!r} both add the command {name!r}; "
                                   "rename one")
            found[name] = (system.name, command)
    return found


def systems() -> list[System]:
    """The registered systems, in the order they were registered (entry points sorted by name, then plug-ins)."""
    _load_builtins()
    return list(_SYSTEMS.values())


def dataset_kinds() -> dict[str, Any]:
    """Every registered dataset kind -> its reader."""
    _load_builtins()
    return dict(_DATASET_KINDS)


def dataset_kind(kind: str) -> Any:
    kinds = dataset_kinds()
    try:
        return kinds[kind]
    except KeyError:
        raise CatalogError(f"unknown dataset kind {kind!r}{did_you_mean(kind, kinds)}; registered kinds: "
                           f"{sorted(kinds)}") from None


def evaluators() -> list[Evaluator]:
    return [e for s in systems() for e in s.evaluators]


def exporters(fmt: str | None = None) -> list[Exporter]:
    """The registered exporters (of one --format), in system order."""
    return [e for s in systems() for e in s.exporters if fmt is None or e.format == fmt]


def comparers() -> list[Comparer]:
    """The systems' compare hooks, in system order."""
    return [s.compare for s in systems() if s.compare is not None]


def report_sections() -> list[ReportSection]:
    return [r for s in systems() for r in s.report]


def weights_reader(schema: str) -> Callable[[Any], dict] | None:
    """The function turning a weights artifact of ``schema`` into plain tensors, where a system declares one."""
    return next((s.weights[schema] for s in systems() if schema in s.weights), None)


def import_plugins(modules: typing.Iterable[str]) -> None:
    """Import plugin modules (each registers its systems, tasks or schemas on import)."""
    _load_builtins()
    for module in modules:
        try:
            importlib.import_module(module)
        except ImportError as exc:
            raise CatalogError(
                f"plugin module {module!r} cannot be imported ({exc}); install it or put it on PYTHONPATH"
            ) from exc


def did_you_mean(word: str, choices: typing.Iterable[str]) -> str:
    close = difflib.get_close_matches(word, list(choices), n=1, cutoff=0.5)
    return f" (did you mean {close[0]!r}?)" if close else ""


def build_params(spec: TaskSpec, raw: Mapping[str, Any], where: Callable[[str], str] = str) -> Any:
    """Check ``raw`` against the task's params dataclass: unknown names, wrong types. Returns an instance.

    ``where(key)`` names the place of a parameter in error messages (file, line, dotted key).
    """
    fields = {f.name: f for f in dataclasses.fields(spec.params)}
    hints = typing.get_type_hints(spec.params)
    values = {}
    for key, value in raw.items():
        if key not in fields:
            raise CatalogError(
                f"{where(key)}: task {spec.name!r} has no parameter {key!r}{did_you_mean(key, fields)}; "
                f"its parameters are {sorted(fields)}"
            )
        values[key] = coerce(value, hints[key], where(key))
    try:
        return spec.params(**values)
    except (TypeError, ValueError) as exc:
        raise CatalogError(f"{where('')}: invalid parameters for task {spec.name!r}: {exc}") from exc


_YAML11_MISSED_FLOAT = re.compile(r"[-+]?(\d+\.?\d*|\.\d+)[eE][-+]?\d+")


def coerce(value: Any, hint: Any, where: str) -> Any:
    """Accept ``value`` for type ``hint`` (int for float, list for tuple) or raise CatalogError."""
    origin = typing.get_origin(hint)
    args = typing.get_args(hint)
    if origin in (typing.Union, types.UnionType):
        for option in args:
            try:
                return coerce(value, option, where)
            except CatalogError:
                continue
        raise CatalogError(f"{where}: {value!r} is not any of {_type_name(hint)}")
    if origin is typing.Literal:
        if value in args:
            return value
        raise CatalogError(f"{where}: {value!r} is not one of {list(args)}")
    if hint is type(None):
        if value is None:
            return None
        raise CatalogError(f"{where}: expected null, got {value!r}")
    if origin in (tuple, list):
        if not isinstance(value, (list, tuple)):
            raise CatalogError(f"{where}: expected a list ({_type_name(hint)}), got {value!r}")
        item = args[0] if args else Any
        items = [coerce(v, item, f"{where}[{i}]") for i, v in enumerate(value)]
        return tuple(items) if origin is tuple else items
    if hint is Any:
        return value
    if dataclasses.is_dataclass(hint) and isinstance(hint, type):
        if isinstance(value, hint):
            return value
        if not isinstance(value, Mapping):
            raise CatalogError(f"{where}: expected a mapping of {hint.__name__} fields, got {value!r}")
        return _build_dataclass(hint, value, where)
    if hint is float and isinstance(value, (int, float)) and not isinstance(value, bool):
        return float(value)
    if hint is float and isinstance(value, str) and _YAML11_MISSED_FLOAT.fullmatch(value):
        return float(value)  # YAML 1.1 reads 1e-3 (no dot) as a string
    if hint is int and isinstance(value, bool):
        raise CatalogError(f"{where}: expected int, got {value!r}")
    if isinstance(hint, type) and isinstance(value, hint):
        return value
    raise CatalogError(f"{where}: expected {_type_name(hint)}, got {type(value).__name__} {value!r}")


def _build_dataclass(cls: type, raw: Mapping[str, Any], where: str) -> Any:
    """A nested settings group (a frozen dataclass field of a config) from a mapping, checked like the config."""
    fields = {f.name for f in dataclasses.fields(cls)}
    hints = typing.get_type_hints(cls)
    for key in raw:
        if key not in fields:
            raise CatalogError(f"{where}.{key}: {cls.__name__} has no field {key!r}{did_you_mean(key, fields)}; "
                               f"its fields are {sorted(fields)}")
    try:
        return cls(**{k: coerce(v, hints[k], f"{where}.{k}") for k, v in raw.items()})
    except (TypeError, ValueError) as exc:
        raise CatalogError(f"{where}: {exc}") from exc


def _type_name(hint: Any) -> str:
    return getattr(hint, "__name__", str(hint))


def _load_builtins() -> None:
    """Register the systems installed under the ``mocapflow.systems`` entry point group (once per process)."""
    global _BUILTINS_LOADED
    if _BUILTINS_LOADED:
        return
    _BUILTINS_LOADED = True
    for point in sorted(entry_points(group=ENTRY_POINT_GROUP), key=lambda p: p.name):
        try:
            system = point.load()
        except Exception as exc:  # a broken plug-in is named, whatever it raised
            raise CatalogError(f"system {point.name!r} ({point.value}) of the {ENTRY_POINT_GROUP!r} entry points "
                               f"cannot be loaded: {type(exc).__name__}: {exc}; fix or uninstall it") from exc
        register_system(system)

"""Registered task implementations and their engine-facing metadata.

tasks/ holds pure array functions; this module says how the engine drives each one: which
stage partition kind it runs on, which artifacts it reads (role -> schema) and writes, its
frozen params dataclass, its explicit code version (bump it when results change), the frame
halo it needs around a region, and which params name weight files (hashed into the cache key;
an empty one means the file shipped in mocapflow.models).
Plugins listed in a catalog register further implementations with :func:`register`.
"""

from __future__ import annotations

import dataclasses
import difflib
import importlib
import inspect
import types
import typing
from dataclasses import dataclass, field
from typing import Any, Callable, Literal, Mapping

from mocapflow.pipeline.errors import CatalogError

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


_REGISTRY: dict[str, TaskSpec] = {}
_BUILTINS_LOADED = False


def register(spec: TaskSpec) -> TaskSpec:
    """Register (or replace) an implementation under ``spec.name``, after checking that its function takes
    exactly its input roles, ``config`` and its weight parameters (a Lazy function: when first imported)."""
    if not dataclasses.is_dataclass(spec.params):
        raise CatalogError(f"task {spec.name!r}: params must be a frozen dataclass, got {spec.params!r}")
    if not spec.params.__dataclass_params__.frozen:
        raise CatalogError(f"task {spec.name!r}: params {spec.params.__name__} must be frozen "
                           "(@dataclass(frozen=True)): a stage's config never changes under a worker")
    roles = task_parameters(spec)
    if isinstance(spec.fn, Lazy):
        spec = dataclasses.replace(spec, fn=dataclasses.replace(spec.fn, roles=roles))
    elif spec.fn is not None:
        check_signature(f"task {spec.name!r}", spec.fn, roles)
    _REGISTRY[spec.name] = spec
    return spec


def task_parameters(spec: TaskSpec) -> tuple[str, ...]:
    """The parameters a task's function takes, in order: its input roles, ``config``, its weight parameters."""
    return (*spec.inputs, "config", *spec.weights_params)


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


def import_plugins(modules: typing.Iterable[str]) -> None:
    """Import plugin modules (each registers its tasks/schemas on import)."""
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
    global _BUILTINS_LOADED
    if _BUILTINS_LOADED:
        return
    _BUILTINS_LOADED = True
    from mocapflow.pipeline import builtin_tasks  # noqa: F401  (registers on import)

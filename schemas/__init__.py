"""Declarative artifact schemas: named dims, dtypes, units, frame chunking, attrs.

An :class:`ArtifactSchema` says what a stage's output looks like. The engine checks it
when a task's output is written and again when a stage reads its inputs, so a stage never
sees an array with the wrong dims, dtype or missing attrs.
"""

from __future__ import annotations

import difflib
import importlib
import pkgutil
from dataclasses import dataclass, field
from typing import Mapping

import numpy as np

__all__ = ["VarSpec", "ArtifactSchema", "register_schema", "get_schema", "SCHEMAS", "SchemaViolation", "UnknownSchema"]


class SchemaViolation(ValueError):
    """Raised by :meth:`ArtifactSchema.validate`; the engine wraps it into its own error."""


class UnknownSchema(LookupError):
    """Raised by :func:`get_schema` for a name no schema is registered under; the engine wraps it into its own error.

    ``name`` is the name asked for, ``registered`` the names known at the time.
    """

    def __init__(self, name: str, registered) -> None:
        self.name = name
        self.registered = tuple(sorted(registered))
        close = difflib.get_close_matches(str(name), self.registered, n=1, cutoff=0.5)
        hint = f" (did you mean {close[0]!r}?)" if close else ""
        super().__init__(f"unknown schema {name!r}{hint}; registered schemas: {list(self.registered)}; "
                         "a schema is registered by importing the module that calls register_schema for it "
                         "(a catalog's plugins are imported when it is loaded)")


@dataclass(frozen=True)
class VarSpec:
    """One array of an artifact: its dims (in order), dtype, units and whether it must exist."""

    dims: tuple[str, ...]
    dtype: str
    units: str = ""
    required: bool = True
    description: str = ""

    def dtype_ok(self, actual: np.dtype) -> bool:
        if self.dtype == "str":
            return actual.kind in "UOT"
        return np.dtype(actual) == np.dtype(self.dtype)


@dataclass(frozen=True)
class ArtifactSchema:
    """Declared layout of one artifact (an xarray Dataset stored as a zarr group)."""

    name: str
    version: int
    variables: Mapping[str, VarSpec]
    coords: Mapping[str, VarSpec] = field(default_factory=dict)
    required_attrs: Mapping[str, type] = field(default_factory=dict)
    frame_chunk: int = 8
    description: str = ""

    def chunks(self, var: str, shape: tuple[int, ...], dims: tuple[str, ...]) -> tuple[int, ...]:
        """Chunk shape of ``var``: ``frame_chunk`` along ``frame``, one along ``view``, whole otherwise."""
        out = []
        for dim, size in zip(dims, shape):
            if dim == "frame":
                out.append(max(1, min(self.frame_chunk, size)))
            elif dim == "view":
                out.append(1)
            else:
                out.append(max(1, size))
        return tuple(out)

    def validate(self, ds) -> None:
        """Check ``ds`` (an xarray Dataset) against this schema; raise SchemaViolation listing every problem."""
        problems: list[str] = []
        for name, spec in {**self.coords, **self.variables}.items():
            if name not in ds.variables:
                if spec.required:
                    problems.append(f"missing variable {name!r} {spec.dims}")
                continue
            var = ds.variables[name]
            if tuple(var.dims) != spec.dims:
                problems.append(f"{name!r} has dims {tuple(var.dims)}, expected {spec.dims}")
            if not spec.dtype_ok(var.dtype):
                problems.append(f"{name!r} has dtype {var.dtype}, expected {spec.dtype}")
        for attr, kind in self.required_attrs.items():
            if attr not in ds.attrs:
                problems.append(f"missing attribute {attr!r} ({kind.__name__})")
            elif not isinstance(ds.attrs[attr], _accepted(kind)):
                problems.append(f"attribute {attr!r} is {type(ds.attrs[attr]).__name__}, expected {kind.__name__}")
        if problems:
            raise SchemaViolation(f"{self.name} v{self.version}: " + "; ".join(problems))


def _accepted(kind: type) -> tuple[type, ...]:
    if kind is float:
        return (float, int, np.floating, np.integer)
    if kind is int:
        return (int, np.integer)
    if kind is list:
        return (list, tuple)
    return (kind,)


SCHEMAS: dict[str, ArtifactSchema] = {}


def register_schema(schema: ArtifactSchema) -> ArtifactSchema:
    """Add ``schema`` to the registry (plugins may add their own); returns it for module-level use."""
    SCHEMAS[schema.name] = schema
    return schema


def get_schema(name: str) -> ArtifactSchema:
    """The schema registered under ``name``; :class:`UnknownSchema` (a LookupError) names the registered ones."""
    _load_builtin()
    try:
        return SCHEMAS[name]
    except KeyError as exc:
        raise UnknownSchema(name, SCHEMAS) from exc


_LOADED = False


def _load_builtin() -> None:
    """Import every module of this package once: each registers the schemas of one system on import (a system's
    plug-in registers its own through its System declaration)."""
    global _LOADED
    if _LOADED:
        return
    _LOADED = True
    for module in pkgutil.iter_modules(__path__):
        importlib.import_module(f"{__name__}.{module.name}")

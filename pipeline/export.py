"""`mocapflow export`: a stage's artifacts as files, one per sequence, through the exporters the systems register.

An exporter (registry.Exporter) names its ``--format``, the schemas it writes out and a function writing one
sequence. Without ``--stage`` the first exporter of the format that finds a stage in the catalog chooses it (its own
rule, else the last stage writing one of its schemas); with ``--stage`` the exporter of that stage's schema writes.
Missing partitions are computed first. Files are written whole or not at all (:func:`write_atomically`), and never
outside ``--out`` (:func:`target`).
"""

from __future__ import annotations

import shutil
import tempfile
from pathlib import Path
from typing import Callable

from mocapflow.pipeline import registry
from mocapflow.pipeline.catalog import final_stage
from mocapflow.pipeline.errors import InputError, PlanError, StorageError
from mocapflow.pipeline.plan import build_plan, select
from mocapflow.pipeline.scheduler import compute_missing
from mocapflow.pipeline.storage import Store

UNIT_SCALE = 1000.0  # metres -> millimetres, the unit of the marker formats


def export_files(catalog, sequences: str | None, fmt: str, stage: str | None, out_dir: Path,
                 workers: int, processes: bool = True, up: str | None = None, force: bool = False) -> list[Path]:
    """Write every sequence of ``stage`` (or the format's default stage) as ``fmt`` into ``out_dir``, computing
    missing partitions first on ``workers`` local worker processes (or threads); ``up`` is an up axis for the
    formats that take one (TRC). A file already in ``out_dir`` is refused unless ``force`` (then overwritten): the
    exporters write into a staging folder there, whose files are moved into place once none is refused. Returns
    the files written."""
    exporters = registry.exporters(fmt)
    if not exporters:
        known = sorted({e.format for e in registry.exporters()})
        raise InputError(f"no system exports the format {fmt!r}; formats: {known}")
    takes_up = sorted({e.format for e in registry.exporters() if "up" in e.options})
    if up is not None and not any("up" in e.options for e in exporters):
        raise InputError(f"--up {up} applies to {', '.join(f.upper() for f in takes_up)} only ({fmt} has a fixed up "
                         "axis); drop --up")
    exporter, stage = choose(catalog, exporters, fmt, stage)
    store = Store(catalog.root)
    plan = build_plan(catalog, sequences)
    for needed in [stage] + (exporter.needs(catalog, stage) if exporter.needs else []):
        compute_missing(select(plan, catalog, store, only=None, until=needed), store, workers=workers,
                        processes=processes, what="cannot export")
    staging = _staging(out_dir)
    try:
        written = []
        for item in plan.for_stages([stage]):
            data = store.open(stage, item.key, item.stage.schema).load()
            job = registry.ExportJob(catalog, plan, store, stage, item.partition.sequence, data, staging, up)
            written += exporter.write(job)
        return _publish([Path(p) for p in written], staging, out_dir, force)
    finally:
        shutil.rmtree(staging, ignore_errors=True)


def _staging(out_dir: Path) -> Path:
    """A new empty folder inside ``out_dir`` (made) for one export's files."""
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
        return Path(tempfile.mkdtemp(prefix=".export-", dir=out_dir))
    except OSError as exc:
        raise StorageError(f"cannot write in --out {out_dir}: {exc.strerror}; choose another --out") from exc


def _publish(files: list[Path], staging: Path, out_dir: Path, force: bool) -> list[Path]:
    """Move the exported ``files`` from ``staging`` to the same names in ``out_dir``; an existing one is refused
    (before any is moved) unless ``force``."""
    moves = [(path, out_dir / path.resolve().relative_to(staging.resolve())) for path in files]
    existing = [dst for _, dst in moves if dst.exists()]
    if existing and not force:
        more = f" (and {len(existing) - 1} more of the files to write)" if len(existing) > 1 else ""
        raise InputError(f"{existing[0]} exists{more}; pass --force to overwrite, or choose another --out")
    for src, dst in moves:
        dst.parent.mkdir(parents=True, exist_ok=True)
        src.replace(dst)
    return [dst for _, dst in moves]


def choose(catalog, exporters: list[registry.Exporter], fmt: str, stage: str | None) -> tuple[registry.Exporter, str]:
    """The exporter and the stage to export: the named stage and the exporter of its schema, else the first
    exporter's default stage that the catalog has."""
    schemas = [s for e in exporters for s in e.schemas]
    wanted = " or ".join(dict.fromkeys(schemas))
    if stage is None:
        for exporter in exporters:
            found = exporter.default_stage(catalog) if exporter.default_stage else \
                next((s for schema in exporter.schemas if (s := final_stage(catalog, schema))), None)
            if found is not None:
                return exporter, found
        raise PlanError(f"the catalog has no stage to export as {fmt} (one writing {wanted}); its stages: "
                        f"{list(catalog.stages)}; choose another --format")
    if stage not in catalog.stages:
        raise PlanError(f"no stage {stage!r} to export as {fmt} (it needs one writing {wanted}); the catalog's stages: "
                        f"{list(catalog.stages)}")
    output = catalog.stages[stage].spec.output
    exporter = next((e for e in exporters if output in e.schemas), None)
    if exporter is None:
        raise PlanError(f"stage {stage!r} writes {output}; {fmt} exports {wanted} — pick another --stage")
    return exporter, stage


def target(out_dir: Path, name: str) -> Path:
    """``out_dir / name``, refused unless it is a file directly inside ``out_dir``."""
    path = out_dir / name
    if path.resolve().parent != out_dir.resolve() or Path(name).name != name:
        raise PlanError(f"export file name {name!r} would be written outside --out {out_dir}; a sequence id must be a "
                        "plain name (see docs/data.md, the naming rule): rename the sequence")
    return path


def write_atomically(path: Path, write: Callable[[Path], None], suffix: str) -> None:
    """``write(tmp)`` then ``tmp`` renamed to ``path``: the file is whole or absent. ``path`` must end in ``suffix``."""
    if path.suffix.lower() != suffix:
        raise InputError(f"export file {path} must end in {suffix}")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_name(path.name + ".partial" + path.suffix)
        write(tmp)
        tmp.replace(path)
    except OSError as exc:
        raise StorageError(f"cannot write {path}: {exc.strerror}; choose another --out") from exc

"""`mocapflow evaluate`: accuracy of the catalog's stages on its evaluation split, against studio ground truth.

Missing partitions are computed first (through the same engine as `mocapflow run`); then every registered
system's evaluator that applies to the catalog (registry.Evaluator: DeepMoCap's, UUO's, the suit's, a plug-in's)
scores its stages. The result holds each evaluator's figures and ``sequences`` (figures per sequence); the headline
and the tables are each evaluator's, in the order the systems are registered.
"""

from __future__ import annotations

import numpy as np

from mocapflow.pipeline import registry
from mocapflow.pipeline.errors import PlanError
from mocapflow.pipeline.plan import Plan, build_plan
from mocapflow.pipeline.storage import Store


def evaluation_plan(catalog, sequences: str | None) -> Plan:
    pattern = sequences or catalog.evaluation.get("sequences")
    return build_plan(catalog, pattern)


def applicable(catalog) -> list[registry.Evaluator]:
    """The evaluators of the registered systems that score some stage of ``catalog``."""
    return [e for e in registry.evaluators() if e.applies(catalog)]


def evaluate(catalog, plan: Plan, store: Store, *, thorough: bool = True) -> dict:
    """Figures per sequence and overall of every evaluator that applies (``thorough`` False: without the figures
    that are slow to score and no figure of the capture itself, such as DeepMoCap's scene flow)."""
    if not plan.sequences:
        raise PlanError("the evaluation split selects no sequence; check evaluation.sequences or --sequences")
    found = applicable(catalog)
    if not found:
        names = [e.name for e in registry.evaluators()]
        raise PlanError(f"the catalog has no stage any system's evaluator scores (evaluators: {names}); add one (see "
                        "catalog.yaml)")
    result: dict = {"sequences": {}}
    for evaluator in found:
        result.update(evaluator.evaluate(catalog, plan, store, result["sequences"], thorough))
    return result


def headline(result: dict) -> dict:
    """The JSON figures `mocapflow evaluate --json` prints: the sequence count, then each evaluator's."""
    out: dict = {"sequences": len(result["sequences"])}
    for evaluator in registry.evaluators():
        out.update(evaluator.headline(result))
    return out


def table(result: dict) -> str:
    """The text tables of every evaluator with figures in ``result``, a blank line between them."""
    parts = [lines for e in registry.evaluators() if (lines := e.table(result))]
    return "\n\n".join("\n".join(lines) for lines in parts)


def format_rows(rows: list[tuple]) -> list[str]:
    """Rows of strings as left-aligned columns, two spaces apart."""
    widths = [max(len(r[c]) for r in rows) for c in range(len(rows[0]))]
    return ["  ".join(c.ljust(w) for c, w in zip(r, widths)).rstrip() for r in rows]


def pct(v: float) -> str:
    """A share as a percentage with two decimals, '-' for NaN."""
    return "-" if np.isnan(v) else f"{100 * v:.2f}"

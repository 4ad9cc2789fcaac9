"""`mocapflow evaluate`: accuracy of the catalog's stages on its evaluation split, against studio ground truth.

Missing partitions are computed first (through the same engine as `mocapflow run`); then every registered
system's evaluator that applies to the catalog (registry.Evaluator: DeepMoCap's, UUO's, the suit's, a plug-in's)
scores its stages. The result holds each evaluator's figures and ``sequences`` (figures per sequence); its headline
figures and text tables are presentation/evaluate.py's.
"""

from __future__ import annotations

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

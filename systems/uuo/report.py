"""UUO in `mocapflow report`: the take's raw markers (the solved body's own page is `mocapflow export --format
report`)."""

from __future__ import annotations

from mocapflow.pipeline.catalog import final_stage
from mocapflow.pipeline.registry import ReportSection
from mocapflow.pipeline.report import Take, base_takes


def applies(catalog) -> bool:
    return final_stage(catalog, "raw_markers") is not None


def takes(catalog, plan, store) -> list[Take]:
    """Every sequence's markers as recorded (the last stage writing raw_markers: a labelled take's merged ones)."""
    return base_takes(catalog, plan, store, final_stage(catalog, "raw_markers"))


SECTION = ReportSection("uuo", applies, takes)

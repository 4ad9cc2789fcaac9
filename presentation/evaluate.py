"""`mocapflow evaluate`'s output: the JSON figures (``--json``) and the text tables of an evaluation's result
(pipeline/evaluate.py computes it), each evaluator's in the order the systems are registered, and the helpers the
systems' tables are written with."""

from __future__ import annotations

import numpy as np

from mocapflow.pipeline import registry


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

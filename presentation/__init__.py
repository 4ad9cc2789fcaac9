"""What people read of a run, above the engine core and below the systems: the report page and its drawing helpers
(report.py), the comparison's table, figures and page (compare.py), the evaluation's text tables and JSON figures
(evaluate.py) and the one interactive 3D viewer both pages carry (viewer.py, its script viewer.js). It knows no
system: what a system shows comes from its registered report sections and evaluators (pipeline/registry.py)."""

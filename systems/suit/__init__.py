"""The checkerboard suit (Chen, Park, Macit, Kavan 2021): coded squares seen by many grey cameras -> labelled
corners -> triangulated, holes filled.

Everything the system adds to the engine, declared in one place: its task specs (tasks.py), schemas, evaluator
(evaluate.py), exporters (export.py: c3d, ply), report section (report.py: its corners as the report's takes, its
figures), the reader of its trained networks and its filming of the studio's takes (film.py: the dataset kind
``studio_suit``, the suit printed on the posed body of a take of systems/studio and filmed by its grey cameras).
The kernels are in tasks/suit.
"""

from mocapflow.pipeline.registry import System
from mocapflow.schemas import suit
from mocapflow.systems.suit import compare, evaluate, export, report, tasks
from mocapflow.systems.suit.film import StudioSuitReader
from mocapflow.tasks.shared.weights import unpack

SYSTEM = System(
    name="suit",
    description="a checkerboard suit of coded squares filmed by grey cameras; labelled corners, triangulated, filled",
    tasks=tasks.TASKS,
    schemas=(suit.SUIT_IMAGES, suit.SUIT_CORNERS, suit.SUIT_QUADS, suit.SUIT_CODES, suit.SUIT_LABELS,
             suit.SUIT_POINTS, suit.SUIT_FILLED, suit.SUIT_NET_WEIGHTS, suit.SUIT_CORNER_SAMPLES,
             suit.SUIT_QUAD_SAMPLES),
    evaluators=(evaluate.EVALUATOR,),
    exporters=export.EXPORTERS,
    report=(report.SECTION,),
    weights={"suit_net_weights": unpack},
    compare=compare.COMPARER,
    dataset_kinds={"studio_suit": StudioSuitReader},
)

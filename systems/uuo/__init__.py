"""UUO (Milef, Keyser, Kong, SIGGRAPH 2024): unlabelled markers anywhere on the body plus a monocular body prior ->
labels, pose and shape.

Everything the system adds to the engine, declared in one place: its task specs (tasks.py), the dataset kinds
``markers`` (readers.py: C3D and TRC recordings, with prior files) and ``studio_markers`` (film.py: the studio's
takes with a UUO marker layout), schemas, evaluator (evaluate.py), exporters
(export.py: c3d, bvh, report) and report section (report.py). The kernels are in tasks/uuo.
"""

from mocapflow.pipeline.registry import System
from mocapflow.schemas import raw, uuo
from mocapflow.systems.uuo import compare, evaluate, export, readers, report, tasks
from mocapflow.systems.uuo.film import StudioMarkersReader

SYSTEM = System(
    name="uuo",
    description="unlabelled optical markers anywhere on the body and a monocular body prior; labels, pose and shape",
    tasks=tasks.TASKS,
    dataset_kinds={"markers": readers.MarkerFileReader, "studio_markers": StudioMarkersReader},
    schemas=(raw.RAW_MARKERS, uuo.MARKER_SEGMENTS, uuo.BODY_PRIOR, uuo.UUO_BODY),
    evaluators=(evaluate.EVALUATOR,),
    exporters=export.EXPORTERS,
    report=(report.SECTION,),
    compare=compare.COMPARER,
)

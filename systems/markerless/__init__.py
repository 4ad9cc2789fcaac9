"""Markerless capture, the peer a user would pick instead of markers: BlazePose's 2D keypoints in each calibrated
view, triangulated with Pose2Sim's outlier rule and read as the template's 20 joints (docs/markerless.md).

Everything the system adds to the engine, declared in one place: its task specs (tasks.py: a source of multi-view
images, the keypoints per view, their triangulation), schemas (schemas.py) and compare hook (compare.py). Its takes
come from the studio's ring of cameras (kind ``studio_suit``: systems/suit/film.py films the studio's take). The
kernels are in tasks/markerless.
"""

from mocapflow.pipeline.registry import System
from mocapflow.systems.markerless import compare, schemas, tasks

SYSTEM = System(
    name="markerless",
    description="BlazePose's 2D keypoints in a few calibrated views, triangulated (Pose2Sim's outlier rule)",
    tasks=tasks.TASKS,
    schemas=(schemas.KEYPOINTS, schemas.JOINTS),
    compare=compare.COMPARER,
)

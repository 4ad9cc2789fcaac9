"""The markerless system's task specs: tasks/markerless."""

from __future__ import annotations

from mocapflow.pipeline.registry import Lazy, NoParams, TaskSpec
from mocapflow.tasks.markerless.blazepose import KeypointsConfig
from mocapflow.tasks.markerless.triangulate import TriangulateConfig
from mocapflow.tasks.shared.cameras import CALIBRATION_VARIABLES as CALIBRATION

TASKS = (
    TaskSpec(
        name="ingest_views", fn=None, version="1", params=NoParams, output="suit_images", partition="sequence",
        source=True,
        description="film or import a dataset's multi-view takes: images of a ring of calibrated cameras (the "
                    "studio's studio_suit kind films them)",
    ),
    TaskSpec(
        name="blazepose_keypoints", fn=Lazy("mocapflow.tasks.markerless.blazepose", "blazepose_keypoints"),
        version="1", params=KeypointsConfig, output="markerless_keypoints", partition="view",
        inputs={"images": "suit_images"}, reads={"images": ("image",)}, weights_params=("detector", "landmarker"),
        description="BlazePose's 33 image landmarks and their confidence in every view, each frame detected afresh",
    ),
    TaskSpec(
        name="triangulate_keypoints", fn=Lazy("mocapflow.tasks.markerless.triangulate", "triangulate_keypoints"),
        version="1", params=TriangulateConfig, output="markerless_joints", partition="sequence",
        inputs={"keypoints": "markerless_keypoints", "images": "suit_images"},
        reads={"keypoints": ("x", "y", "confidence"), "images": CALIBRATION},
        description="keypoints triangulated from every confident view, the worst view dropped while its "
                    "reprojection error passes the threshold (Pose2Sim), read as the template's 20 joints",
    ),
)

"""Registrations of the built-in stage implementations (see registry.py)."""

from __future__ import annotations

from mocapflow.pipeline.registry import Lazy, NoParams, TaskSpec, register
from mocapflow.tasks import flow, masks

CALIBRATION = ("fx", "fy", "cx", "cy", "dist", "width", "height")

# The `frames` stage: every raw sequence of a dataset synthesized (studio) or imported
# (zarr, image folders) into the raw-sequence schema. The dataset reader runs it.
register(
    TaskSpec(
        name="ingest",
        fn=None,
        version="1",
        params=NoParams,
        output="raw_sequence",
        partition="sequence",
        source=True,
        description="synthesize or import a dataset's sequences into the raw-sequence schema",
    )
)

register(TaskSpec(
    name="reflector_mask", fn=masks.masks, version="1", params=masks.MaskConfig, output="reflector_masks",
    partition="view", inputs={"frames": "raw_sequence"}, reads={"frames": ("depth", "ir")},
    description="IR threshold, morphology, connected components; colorized depth with reflectors black",
))
register(TaskSpec(
    name="dis", fn=flow.dis, version="1", params=flow.DisConfig, output="scene_flow", partition="view",
    inputs={"frames": "raw_sequence"}, reads={"frames": ("depth", "ir") + CALIBRATION}, halo=(1, 0),
    description="OpenCV DIS optical flow on IR, lifted to 3D with both depth maps",
))
register(TaskSpec(
    name="primal_dual", fn=Lazy("mocapflow.tasks.pdflow", "primal_dual"), version="2", params=flow.PrimalDualConfig,
    output="scene_flow",
    partition="view", inputs={"frames": "raw_sequence"}, reads={"frames": ("depth", "ir") + CALIBRATION},
    halo=(1, 0), description="primal-dual RGB-D scene flow (Jaimez et al. 2015) on IR + depth, torch",
))

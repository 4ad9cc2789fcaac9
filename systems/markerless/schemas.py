"""Schemas of the markerless system: BlazePose's 2D keypoints per view, and the keypoints triangulated and read as
the template's joints. Its input is a multi-view image set with calibration (``suit_images``: the studio's ring of
cameras; only the images, the calibration and the truth are read)."""

from __future__ import annotations

from mocapflow.schemas import ArtifactSchema, VarSpec, register_schema

_FRAME = {"frame": VarSpec(("frame",), "int64", description="frame index from 0")}
_VIEW = {"view": VarSpec(("view",), "str", description="camera name")}
_LANDMARK = {"landmark": VarSpec(("landmark",), "str", description="BlazePose's landmark name (33)")}

KEYPOINTS = register_schema(ArtifactSchema(
    name="markerless_keypoints",
    version=1,
    coords={**_VIEW, **_FRAME, **_LANDMARK},
    variables={
        "x": VarSpec(("view", "frame", "landmark"), "float32", "px", description="image x (distorted), NaN: no body"),
        "y": VarSpec(("view", "frame", "landmark"), "float32", "px"),
        "confidence": VarSpec(("view", "frame", "landmark"), "float32",
                              description="visibility times the frame's presence flag, 0 where no body"),
        "presence": VarSpec(("view", "frame"), "float32", description="the landmark network's presence flag"),
    },
    frame_chunk=8,
    description="BlazePose's 33 image landmarks per view and frame, with their confidence",
))

JOINTS = register_schema(ArtifactSchema(
    name="markerless_joints",
    version=1,
    coords={**_FRAME, **_VIEW, **_LANDMARK, "joint": VarSpec(("joint",), "str", description="template joint")},
    variables={
        "joints": VarSpec(("frame", "joint", "xyz"), "float32", "m", description="NaN where not given"),
        "joint_confidence": VarSpec(("frame", "joint"), "float32",
                                    description="the least confidence of the landmarks the joint reads"),
        "landmarks": VarSpec(("frame", "landmark", "xyz"), "float32", "m", description="NaN where not given"),
        "kept": VarSpec(("frame", "view", "landmark"), "bool", description="the view was used"),
        "swapped": VarSpec(("frame", "view"), "bool", description="the view's landmarks were read left for right"),
        "dropped": VarSpec(("frame", "view", "landmark"), "bool", description="the outlier rule dropped the view"),
        "error": VarSpec(("frame", "view", "landmark"), "float32", "px",
                         description="reprojection error of the final point in each observing view"),
    },
    required_attrs={"length_unit": str, "up_axis": str, "fps": float},
    frame_chunk=16,
    description="BlazePose's landmarks triangulated (Pose2Sim's outlier rule) and the template's 20 joints",
))

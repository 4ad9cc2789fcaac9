"""Schemas of the per-view input stages: reflector masks with colorized depth, and 3D optical flow."""

from __future__ import annotations

from mocapflow.schemas import ArtifactSchema, VarSpec, register_schema

_VIEW_FRAME = {"view": VarSpec(("view",), "str"), "frame": VarSpec(("frame",), "int64")}

REFLECTOR_MASKS = register_schema(ArtifactSchema(
    name="reflector_masks",
    version=1,
    coords=_VIEW_FRAME,
    variables={
        "mask": VarSpec(("view", "frame", "y", "x"), "bool", description="reflector pixels (IR threshold)"),
        "blob_id": VarSpec(("view", "frame", "y", "x"), "uint16", description="0 none, else blob 1..K"),
        "blob_area": VarSpec(("view", "frame", "blob"), "int32", "px", description="area of blob k+1 (0 unused)"),
        "colorized_depth": VarSpec(("view", "frame", "y", "x", "rgb"), "uint8",
                                   description="I_CD: JET depth, reflectors and invalid depth black"),
    },
    required_attrs={"ir_threshold": int, "near_mm": float, "far_mm": float},
    frame_chunk=8,
    description="reflector masks and colorized depth (DeepMoCap §3.2)",
))

SCENE_FLOW = register_schema(ArtifactSchema(
    name="scene_flow",
    version=1,
    coords=_VIEW_FRAME,
    variables={
        "flow": VarSpec(("view", "frame", "y", "x", "xyz"), "float16", "m",
                        description="camera-frame motion from frame f-1 to f at the pixels of frame f"),
        "valid": VarSpec(("view", "frame", "y", "x"), "bool"),
        "colorized_flow": VarSpec(("view", "frame", "y", "x", "rgb"), "uint8",
                                  description="I_F: each motion axis normalized into one channel"),
    },
    required_attrs={"color_scale_m": float},
    frame_chunk=8,
    description="3D optical flow (DeepMoCap §3.2)",
))

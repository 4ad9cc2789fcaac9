"""Schemas of the 3D optical data (DeepMoCap §3.4): fused labelled reflectors and their smoothed tracks."""

from __future__ import annotations

from mocapflow.schemas import ArtifactSchema, VarSpec, register_schema

_COORDS = {"frame": VarSpec(("frame",), "int64"), "reflector": VarSpec(("reflector",), "str"),
           "xyz": VarSpec(("xyz",), "str")}
_ATTRS = {"length_unit": str, "up_axis": str, "fps": float}

MARKERS3D = register_schema(ArtifactSchema(
    name="markers3d",
    version=2,
    coords={**_COORDS, "view": VarSpec(("view",), "str")},
    variables={
        "position": VarSpec(("frame", "reflector", "xyz"), "float32", "m", description="world position, NaN if unseen"),
        "confidence": VarSpec(("frame", "reflector"), "float32", description="C_f: mean of the fused views' E"),
        "views": VarSpec(("frame", "reflector"), "int8", description="views fused"),
        "residual": VarSpec(("frame", "reflector", "view"), "float32", "m",
                            description="each view's distance from the fused point, NaN if unseen"),
        "view_position": VarSpec(("frame", "reflector", "view", "xyz"), "float32", "m",
                                 description="each view's own estimate of the reflector centre, NaN if unseen"),
        "view_confidence": VarSpec(("frame", "reflector", "view"), "float32",
                                   description="each view's 2D confidence E of that estimate, 0 if unseen"),
    },
    required_attrs=_ATTRS,
    frame_chunk=64,
    description="labelled 3D reflectors fused over views (DeepMoCap §3.4.1-3.4.2)",
))

SMOOTHED = register_schema(ArtifactSchema(
    name="smoothed_markers",
    version=1,
    coords=_COORDS,
    variables={
        "position": VarSpec(("frame", "reflector", "xyz"), "float32", "m", description="filtered position, NaN if missing"),
        "confidence": VarSpec(("frame", "reflector"), "float32", description="0 where predicted or missing"),
        "predicted": VarSpec(("frame", "reflector"), "bool", description="no measurement used: predicted in a gap"),
        "rejected": VarSpec(("frame", "reflector"), "int8", required=False,
                            description="why a marker was removed: 0 kept, 1 outside the capture volume, 2 off the body"),
    },
    required_attrs={**_ATTRS, "smoothing": str},
    frame_chunk=64,
    description="temporally filtered labelled 3D reflectors",
))

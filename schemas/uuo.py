"""Schemas of the UUO solver's stages (Milef et al. 2024): marker groups, part labels, body fits."""

from __future__ import annotations

from mocapflow.schemas import ArtifactSchema, VarSpec, register_schema

MARKER_SEGMENTS = register_schema(ArtifactSchema(
    name="marker_segments",
    version=1,
    coords={"marker": VarSpec(("marker",), "str", description="trajectory id of the raw markers")},
    variables={
        "segment": VarSpec(("marker",), "int64",
                           description="rigid group of the trajectory (§3.4.1), numbered by size, largest first"),
    },
    required_attrs={"segments": int},
    description="markers grouped by the bone they ride (spread of pairwise distances, agglomerative clustering)",
))

BODY_PRIOR = register_schema(ArtifactSchema(
    name="body_prior",
    version=1,
    coords={"frame": VarSpec(("frame",), "int64"), "bone": VarSpec(("bone",), "str"), "joint": VarSpec(("joint",), "str")},
    variables={
        "bone_rotation": VarSpec(("frame", "bone", "quat"), "float64", "",
                                 description="each mesh bone's world rotation from its rest orientation, x y z w"),
        "root": VarSpec(("frame", "xyz"), "float64", "m", description="the root bone's head"),
        "joints": VarSpec(("frame", "joint", "xyz"), "float32", "m", description="the prior body's 20 template joints"),
        "valid": VarSpec(("frame",), "bool", description="False where the estimator lost the frame (held)"),
    },
    required_attrs={"fps": float, "phenotype": dict, "source": str},
    frame_chunk=64,
    description="a rough body per frame from monocular video (UUO §3.3): pose, root and shape, with unknown "
                "global translation, size and yaw",
))

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

UUO_BODY = register_schema(ArtifactSchema(
    name="uuo_body",
    version=1,
    coords={"frame": VarSpec(("frame",), "int64"), "bone": VarSpec(("bone",), "str"),
            "joint": VarSpec(("joint",), "str"), "marker": VarSpec(("marker",), "str"),
            "stage": VarSpec(("stage",), "str", description="matching, pose_fit, ik, refined (§3.4-3.5)")},
    variables={
        "bone_rotation": VarSpec(("frame", "bone", "quat"), "float64", "",
                                 description="each mesh bone's world rotation from its rest orientation, x y z w"),
        "root": VarSpec(("frame", "xyz"), "float64", "m", description="the root bone's head"),
        "joints": VarSpec(("frame", "joint", "xyz"), "float32", "m", description="the 20 template joints"),
        "bone_heads": VarSpec(("frame", "bone", "xyz"), "float32", "m", description="every Anny bone's head"),
        "stage_joints": VarSpec(("stage", "frame", "joint", "xyz"), "float32", "m",
                                description="the joints after each solver stage (NaN: not run); Table 4's rows"),
        "vertex": VarSpec(("marker",), "int64", description="the body vertex of each trajectory, -1 unlabelled"),
        "part": VarSpec(("marker",), "str", description="the body part of that vertex, empty when unlabelled"),
        "marker_distance": VarSpec(("marker",), "float64", "m",
                                   description="mean distance from the trajectory to its vertex (Eq. 6)"),
    },
    required_attrs={"phenotype": dict, "chamfer": float, "yaw_deg": float, "parts": list},
    frame_chunk=64,
    description="a body solved from unlabelled markers (UUO §3.5): pose, root and shape per take, each marker's "
                "vertex and part",
))

UUO_SCREEN = register_schema(ArtifactSchema(
    name="uuo_screen",
    version=1,
    coords={"hypothesis": VarSpec(("hypothesis",), "int64",
                                  description="rank: the placements facing apart first, then the rest by chamfer")},
    variables={
        "yaw_deg": VarSpec(("hypothesis",), "float64", "deg", description="the root yaw part matching started from"),
        "mirror": VarSpec(("hypothesis",), "bool", description="the prior mirrored left-right"),
        "matched_yaw_deg": VarSpec(("hypothesis",), "float64", "deg", description="the yaw part matching ended at"),
        "chamfer": VarSpec(("hypothesis",), "float64", "m2", description="Eq. (1) on the search's frames"),
        "parts": VarSpec(("hypothesis",), "str", description="the matched chain of parts, comma-separated"),
    },
    required_attrs={"distinct": int, "symmetric_prior": bool, "step_deg": float},
    description="the prior placed on the markers from every root yaw and mirrored, ranked (UUO §3.5.1, widened)",
))

"""Schemas of the 2D reflector-set estimation (DeepMoCap §3.3): training samples, FCN weights,
heatmaps (confidence maps S and optical flow fields L) and the labelled 2D reflectors."""

from __future__ import annotations

from mocapflow.schemas import ArtifactSchema, VarSpec, register_schema

_VIEW_FRAME = {"view": VarSpec(("view",), "str"), "frame": VarSpec(("frame",), "int64")}
_PER_REFLECTOR = ("view", "frame", "reflector")

FCN_SAMPLES = register_schema(ArtifactSchema(
    name="fcn_samples",
    version=2,
    coords=_VIEW_FRAME,
    variables={
        "depth_image": VarSpec(("view", "frame", "y", "x", "rgb"), "uint8", description="I_CD at the sample scale"),
        "flow_image": VarSpec(("view", "frame", "y", "x", "rgb"), "uint8", description="I_F at the sample scale"),
        "box": VarSpec(("view", "frame", "corner"), "float32", "px", description="subject box x0 y0 x1 y1"),
        "gt_uv": VarSpec(_PER_REFLECTOR + ("uv",), "float32", "px", description="ground-truth 2D at frame f"),
        "gt_uv_prev": VarSpec(_PER_REFLECTOR + ("uv",), "float32", "px", description="ground-truth 2D at frame f-1"),
        "gt_pixels": VarSpec(_PER_REFLECTOR, "int32", "px", description="visible pixels of each reflector"),
    },
    required_attrs={"sample_scale": float},
    frame_chunk=1,  # the training reads one sample (view-frame) at a time: a chunk per frame decodes only it
    description="FCN training samples: both input streams and the ground truth, at the sample scale",
))

FCN_WEIGHTS = register_schema(ArtifactSchema(
    name="fcn_weights",
    version=1,
    variables={
        "weights": VarSpec(("parameter",), "float32", description="every tensor of the state dict, flattened"),
        "loss": VarSpec(("iteration",), "float32", description="training loss per iteration (all stages)"),
    },
    required_attrs={"architecture": dict, "layout": list, "training": dict},
    description="a trained two-stream FCN: its architecture, tensor layout and weights",
))

HEATMAPS = register_schema(ArtifactSchema(
    name="heatmaps",
    version=1,
    coords={**_VIEW_FRAME, "reflector": VarSpec(("reflector",), "str")},
    variables={
        "confidence": VarSpec(("view", "frame", "reflector", "hy", "hx"), "float16",
                              description="confidence maps S (Eq. 4) on the network's output grid"),
        "off": VarSpec(("view", "frame", "reflector", "hy", "hx", "uv"), "float16",
                       description="optical flow fields L (Eq. 5-6): unit motion f-1 -> f"),
        "crop": VarSpec(("view", "frame", "affine"), "float64", "px",
                        description="2x3 affine, row-major: network input pixel -> image pixel"),
    },
    required_attrs={"stride": int},
    frame_chunk=8,
    description="per-reflector confidence maps and optical flow fields of the two-stream FCN (DeepMoCap §3.3)",
))

REFLECTORS2D = register_schema(ArtifactSchema(
    name="reflectors2d",
    version=1,
    coords={**_VIEW_FRAME, "reflector": VarSpec(("reflector",), "str")},
    variables={
        "x": VarSpec(_PER_REFLECTOR, "float32", "px", description="accepted estimate (region centre), NaN if none"),
        "y": VarSpec(_PER_REFLECTOR, "float32", "px"),
        "confidence": VarSpec(_PER_REFLECTOR, "float32", description="fused confidence E (Eq. 9); 0 if none"),
        "region_size": VarSpec(_PER_REFLECTOR, "int32", "px", description="pixels of the reflector region; 0 if none"),
        "recovered": VarSpec(_PER_REFLECTOR, "bool", required=False,
                             description="kept by the second filtering pass (GreedyConfig recover_*); markers3d "
                                         "lifts it only with lift_recovered, where no view has a plain estimate"),
        "exchanged": VarSpec(_PER_REFLECTOR, "bool", required=False,
                             description="label taken from the mirrored reflector's estimate (refine_reflectors)"),
        "reprojected": VarSpec(_PER_REFLECTOR, "bool", required=False,
                               description="added where the solved poses project onto a free region (refine_reflectors)"),
        "candidate_x": VarSpec(_PER_REFLECTOR, "float32", "px", description="best candidate before filtering"),
        "candidate_y": VarSpec(_PER_REFLECTOR, "float32", "px"),
        "candidate_confidence": VarSpec(_PER_REFLECTOR, "float32"),
    },
    required_attrs={"b_min": int, "c_min": float},
    frame_chunk=8,
    description="labelled 2D reflectors per view and frame (DeepMoCap §3.3.3, §5.1.3)",
))

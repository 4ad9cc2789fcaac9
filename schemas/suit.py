"""Schemas of the checkerboard-suit system (Chen et al. 2021): the grey cameras' images with the suit's pattern,
the 2D chain (corners, candidate quads, their codes, labelled corners), the triangulated and the filled corners.

Corners are numbered by the suit's pattern (``corner``: 0..N-1); a coded white square is a ``square`` with a
two-letter code and its four corners in quad order (``k`` = 0..3, clockwise from the upright top-left). Per-image
lists of unknown length (detections, candidate quads) are padded along ``detection`` / ``quad`` to the stage's
capacity: NaN coordinates, -1 indices.
"""

from __future__ import annotations

from mocapflow.schemas import ArtifactSchema, VarSpec, register_schema
from mocapflow.schemas.raw import CALIBRATION

_FRAME = {"frame": VarSpec(("frame",), "int64", description="frame index from 0")}
_VIEW = {"view": VarSpec(("view",), "str", description="camera name")}
_CORNER = {"corner": VarSpec(("corner",), "int64", description="the suit's corner number")}

SUIT_IMAGES = register_schema(ArtifactSchema(
    name="suit_images",
    version=1,
    coords={**_VIEW, **_FRAME, **_CORNER},
    variables={
        "image": VarSpec(("view", "frame", "y", "x"), "uint8", "counts", description="grey camera image"),
        "timestamp": VarSpec(("frame",), "float64", "s"),
        **CALIBRATION,
        # The suit's pattern: codes, their corners, the corner mesh and where each corner sits on the body model.
        "code": VarSpec(("square",), "str", description="two-letter code of each coded white square"),
        "square_corners": VarSpec(("square", "k"), "int64",
                                  description="corner of quad vertex k, clockwise from the upright code's top-left"),
        "cells": VarSpec(("cell", "k"), "int64", description="grid squares (black and white) whose corners all exist"),
        "corner_face": VarSpec(("corner",), "int64", description="body-model face under the corner"),
        "corner_bary": VarSpec(("corner", "uv"), "float64", description="barycentric (u, v) on that face"),
        # Optional ground truth (the studio writes these).
        "gt_corners": VarSpec(("frame", "corner", "xyz"), "float32", "m", required=False),
        "gt_corners2d": VarSpec(("view", "frame", "corner", "uv"), "float32", "px", required=False,
                                description="true pixel (x, y), lens distortion included"),
        "gt_visible": VarSpec(("view", "frame", "corner"), "bool", required=False,
                              description="in the image, facing the camera, not hidden"),
        "gt_readable": VarSpec(("view", "frame", "corner"), "bool", required=False,
                               description="a coded square of the corner is wholly seen near face-on"),
        "gt_joints": VarSpec(("frame", "joint", "xyz"), "float32", "m", required=False),
        "gt_bone_rotations": VarSpec(("frame", "bone", "quat"), "float64", "", required=False),
        "gt_root": VarSpec(("frame", "xyz"), "float64", "m", required=False),
    },
    required_attrs={"fps": float, "suit": str},
    frame_chunk=4,
    description="synchronized grey multi-camera images of a subject in the checkerboard suit, with calibration and "
                "the suit's pattern",
))

SUIT_CORNERS = register_schema(ArtifactSchema(
    name="suit_corners",
    version=1,
    coords={**_VIEW, **_FRAME},
    variables={
        "x": VarSpec(("view", "frame", "detection"), "float32", "px", description="NaN past the frame's detections"),
        "y": VarSpec(("view", "frame", "detection"), "float32", "px"),
        "logit": VarSpec(("view", "frame", "detection"), "float32", description="CornerdetNet's presence logit"),
    },
    frame_chunk=16,
    description="checkerboard-like corners found in each image (CornerdetNet, §3.1)",
))

SUIT_QUADS = register_schema(ArtifactSchema(
    name="suit_quads",
    version=1,
    coords={**_VIEW, **_FRAME},
    variables={
        "detections": VarSpec(("view", "frame", "quad", "k"), "int32",
                              description="the quad's four detections, clockwise in the image; -1 past the list"),
    },
    frame_chunk=16,
    description="candidate quads: convex clockwise 4-sets of detected corners that pass the early filters (§3.2)",
))

SUIT_CODES = register_schema(ArtifactSchema(
    name="suit_codes",
    version=1,
    coords={**_VIEW, **_FRAME},
    variables={
        "accepted": VarSpec(("view", "frame", "quad"), "bool", description="RejectorNet: a valid quad with a legible code"),
        "rotation": VarSpec(("view", "frame", "quad"), "int8",
                            description="quarter turns from the quad's order to the upright code's, -1 rejected"),
        "code": VarSpec(("view", "frame", "quad"), "int16",
                        description="RecogNet's reading: first * 25 + second character's index in the alphabet, "
                                    "-1 rejected"),
        "confidence": VarSpec(("view", "frame", "quad"), "float32", description="RecogNet's code probability"),
    },
    frame_chunk=16,
    description="candidate quads accepted by RejectorNet and read by RecogNet (§3.2)",
))

SUIT_LABELS = register_schema(ArtifactSchema(
    name="suit_labels",
    version=1,
    coords={**_VIEW, **_FRAME, **_CORNER},
    variables={
        "x": VarSpec(("view", "frame", "corner"), "float32", "px", description="NaN where not labelled"),
        "y": VarSpec(("view", "frame", "corner"), "float32", "px"),
        "quads": VarSpec(("view", "frame", "corner"), "int8", description="accepted quads naming the corner (0-2)"),
    },
    frame_chunk=16,
    description="uniquely labelled corners per image, after the redundancy check (§3.3)",
))

SUIT_POINTS = register_schema(ArtifactSchema(
    name="suit_points",
    version=1,
    coords={**_FRAME, **_CORNER, **_VIEW},
    variables={
        "position": VarSpec(("frame", "corner", "xyz"), "float32", "m", description="NaN where not reconstructed"),
        "kept": VarSpec(("frame", "view", "corner"), "bool", description="the view's claim was used"),
        "error": VarSpec(("frame", "view", "corner"), "float32", "px",
                         description="reprojection error of the final point in each claiming view, NaN unclaimed"),
        "hidden": VarSpec(("frame", "corner"), "bool", required=False,
                          description="an observation hidden to score the filling (tasks/suit/holdout.py)"),
        "hidden_position": VarSpec(("frame", "corner", "xyz"), "float32", "m", required=False,
                                   description="the hidden observation's triangulated position, NaN elsewhere"),
    },
    required_attrs={"length_unit": str, "up_axis": str, "fps": float},
    frame_chunk=16,
    description="labelled corners triangulated from every view that claims them, outlier views dropped (§3.3)",
))

SUIT_FILLED = register_schema(ArtifactSchema(
    name="suit_filled",
    version=1,
    coords={**_FRAME, **_CORNER},
    variables={
        "position": VarSpec(("frame", "corner", "xyz"), "float32", "m", description="every corner, observed or filled"),
        "observed": VarSpec(("frame", "corner"), "bool", description="triangulated (True) or filled (False)"),
    },
    required_attrs={"length_unit": str, "up_axis": str, "fps": float},
    frame_chunk=64,
    description="the whole suit per frame: observed corners kept, holes filled by the spatio-temporal Laplacian (§5)",
))

SUIT_NET_WEIGHTS = register_schema(ArtifactSchema(
    name="suit_net_weights",
    version=1,
    variables={
        "weights": VarSpec(("parameter",), "float32", description="every tensor of the state dict, flattened"),
        "loss": VarSpec(("iteration",), "float32", description="training loss per iteration"),
    },
    required_attrs={"architecture": dict, "layout": list, "training": dict},
    description="a trained network of the suit's 2D chain (CornerdetNet, RejectorNet or RecogNet): its "
                "architecture, tensor layout, weights and training record",
))

SUIT_CORNER_SAMPLES = register_schema(ArtifactSchema(
    name="suit_corner_samples",
    version=1,
    coords={**_VIEW, **_FRAME},
    variables={
        "crops": VarSpec(("view", "frame", "crop", "cy", "cx"), "uint8", "counts", description="20 x 20 grey crops"),
        "present": VarSpec(("view", "frame", "crop"), "bool", description="a corner in the central 8 x 8 cell"),
        "position": VarSpec(("view", "frame", "crop", "uv"), "float32",
                            description="the corner's (x, y) normalised in the cell, 0 where absent"),
        "used": VarSpec(("view", "frame", "crop"), "bool", description="False past the image's crops (padding)"),
    },
    frame_chunk=4,
    description="CornerdetNet's training crops cut from studio images with their truth (§4.1)",
))

SUIT_QUAD_SAMPLES = register_schema(ArtifactSchema(
    name="suit_quad_samples",
    version=1,
    coords={**_VIEW, **_FRAME},
    variables={
        "crops": VarSpec(("view", "frame", "crop", "qy", "qx"), "uint8", "counts",
                         description="candidate quads of detected corners warped to 104 x 104"),
        "valid": VarSpec(("view", "frame", "crop"), "bool", description="the four corners of a coded square"),
        "rotation": VarSpec(("view", "frame", "crop"), "int8", description="quarter turns, -1 invalid"),
        "code": VarSpec(("view", "frame", "crop"), "int16", description="code index, -1 invalid"),
        "used": VarSpec(("view", "frame", "crop"), "bool", description="False past the image's crops (padding)"),
    },
    frame_chunk=2,
    description="RejectorNet's and RecogNet's training crops: candidate quads of studio images labelled from the truth",
))

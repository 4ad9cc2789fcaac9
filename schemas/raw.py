"""Raw-sequence schema: synchronized multi-view IR + depth with calibration and timing.

Depth is Kinect-v2-like uint16 millimetres (0 = invalid), IR uint16 counts. Calibration
follows OpenCV: pinhole intrinsics ``fx fy cx cy`` in pixels, distortion ``k1 k2 p1 p2 k3``,
and a 4x4 camera-to-world transform with translation in metres (world is Z-up, metres).
Ground-truth variables (``gt_*``) are optional: the studio writes them, real recordings lack them.
"""

from __future__ import annotations

from typing import Mapping

import numpy as np
import xarray as xr

from mocapflow.schemas import ArtifactSchema, VarSpec, register_schema

DIST_COEFS = ("k1", "k2", "p1", "p2", "k3")
# Each view's calibration, as every multi-camera recording stores it.
CALIBRATION = {
    "fx": VarSpec(("view",), "float64", "px"),
    "fy": VarSpec(("view",), "float64", "px"),
    "cx": VarSpec(("view",), "float64", "px"),
    "cy": VarSpec(("view",), "float64", "px"),
    "dist": VarSpec(("view", "dist_coef"), "float64", "", description="OpenCV k1 k2 p1 p2 k3"),
    "cam_to_world": VarSpec(("view", "row", "col"), "float64", "m", description="4x4 rigid transform"),
    "width": VarSpec(("view",), "int64", "px"),
    "height": VarSpec(("view",), "int64", "px"),
}

RAW_SEQUENCE = register_schema(
    ArtifactSchema(
        name="raw_sequence",
        version=1,
        coords={
            "view": VarSpec(("view",), "str", description="sensor name"),
            "frame": VarSpec(("frame",), "int64", description="frame index from 0"),
        },
        variables={
            "depth": VarSpec(("view", "frame", "y", "x"), "uint16", "mm", description="0 where invalid"),
            "ir": VarSpec(("view", "frame", "y", "x"), "uint16", "counts"),
            "timestamp": VarSpec(("frame",), "float64", "s"),
            **CALIBRATION,
            # Optional ground truth (the synthetic studio writes these).
            "gt_joints": VarSpec(("frame", "joint", "xyz"), "float32", "m", required=False),
            "gt_reflectors": VarSpec(("frame", "reflector", "xyz"), "float32", "m", required=False),
            "gt_reflectors2d": VarSpec(("view", "frame", "reflector", "uv"), "float32", "px", required=False),
            "gt_visible": VarSpec(("view", "frame", "reflector"), "bool", required=False),
            "gt_pixels": VarSpec(("view", "frame", "reflector"), "int32", "px", required=False),
            "gt_reflector_id": VarSpec(
                ("view", "frame", "y", "x"), "int8", required=False, description="-1 none, else reflector index"
            ),
            "gt_joint_rotations": VarSpec(("frame", "joint", "quat"), "float32", "", required=False,
                                          description="local joint rotations, quaternions x y z w"),
            "gt_bone_rotations": VarSpec(("frame", "bone", "quat"), "float64", "", required=False,
                                         description="mesh body: each bone's world rotation from its rest "
                                                     "orientation, quaternions x y z w"),
            "gt_root": VarSpec(("frame", "xyz"), "float64", "m", required=False,
                               description="mesh body: the root bone's head (with the bone rotations and the "
                                           "phenotype attribute, every vertex)"),
            "gt_body": VarSpec(("view", "frame", "y", "x"), "bool", required=False,
                               description="the subject's body is the visible surface"),
            "gt_scene_flow": VarSpec(
                ("view", "frame", "y", "x", "xyz"), "float16", "m",
                required=False, description="camera-frame 3D motion of the visible surface to the next frame",
            ),
            "gt_scene_flow_prev": VarSpec(
                ("view", "frame", "y", "x", "xyz"), "float16", "m", required=False,
                description="camera-frame 3D motion of the visible surface from the previous frame (0 at frame 0)",
            ),
        },
        required_attrs={"fps": float},
        frame_chunk=8,
        description="synchronized multi-view IR-depth recording with calibration",
    )
)


def make_raw_sequence(depth: np.ndarray, ir: np.ndarray, cameras: Mapping[str, Mapping], fps: float,
                      first_frame: int, extra: Mapping[str, tuple] | None = None) -> xr.Dataset:
    """Build a raw-sequence Dataset from arrays ``(view, frame, y, x)`` and per-view calibration dicts."""
    views = list(cameras)
    n = depth.shape[1]
    frames = np.arange(first_frame, first_frame + n, dtype=np.int64)
    cam = [cameras[v] for v in views]
    data = {
        "depth": (("view", "frame", "y", "x"), depth.astype(np.uint16)),
        "ir": (("view", "frame", "y", "x"), ir.astype(np.uint16)),
        "timestamp": (("frame",), frames / float(fps)),
        "dist": (("view", "dist_coef"), np.array([np.asarray(c["dist"], float) for c in cam])),
        "cam_to_world": (("view", "row", "col"), np.array([np.asarray(c["cam_to_world"], float) for c in cam])),
        **{k: (("view",), np.array([float(c[k]) for c in cam])) for k in ("fx", "fy", "cx", "cy")},
        **{k: (("view",), np.array([int(c[k]) for c in cam], dtype=np.int64)) for k in ("width", "height")},
        **(extra or {}),
    }
    coords = {"view": np.array(views, dtype=object), "frame": frames, "dist_coef": np.array(DIST_COEFS, dtype=object)}
    return xr.Dataset(data, coords=coords, attrs={"fps": float(fps), "length_unit": "m", "depth_unit": "mm",
                                                  "up_axis": "Z"})


RAW_MARKERS = register_schema(
    ArtifactSchema(
        name="raw_markers",
        version=1,
        coords={
            "frame": VarSpec(("frame",), "int64", description="frame index from 0"),
            "marker": VarSpec(("marker",), "str", description="trajectory id (the file's label, or m000... when "
                                                               "labels are ignored)"),
        },
        variables={
            "position": VarSpec(("frame", "marker", "xyz"), "float32", "m",
                                description="marker centre, world Z up; NaN where the trajectory has no sample"),
            "timestamp": VarSpec(("frame",), "float64", "s"),
            "label": VarSpec(("marker",), "str", required=False, description="the file's own label"),
            # Optional ground truth (the studio's unlabelled takes on the mesh body write these).
            "gt_source": VarSpec(("marker",), "int64", required=False,
                                 description="the true marker a trajectory follows, -1 for a ghost"),
            "gt_face": VarSpec(("marker",), "int64", required=False,
                               description="mesh face of the trajectory's skin point, -1 for a ghost"),
            "gt_bary": VarSpec(("marker", "uv"), "float64", required=False,
                               description="barycentric (u, v) of the skin point on gt_face, NaN for a ghost"),
            "gt_path": VarSpec(("frame", "marker", "xyz"), "float32", "m", required=False,
                               description="the true centre the trajectory follows, never hidden, NaN for a ghost"),
            "gt_joints": VarSpec(("frame", "joint", "xyz"), "float32", "m", required=False),
            "gt_bone_rotations": VarSpec(("frame", "bone", "quat"), "float64", "", required=False),
            "gt_root": VarSpec(("frame", "xyz"), "float64", "m", required=False),
            # Optional monocular prior brought with a recording (systems/uuo/prior_files.py): the template's joints.
            "prior_joints": VarSpec(("frame", "joint", "xyz"), "float32", "m", required=False,
                                    description="a monocular estimate's joints (JOINT_NAMES), NaN on lost frames"),
            # Optional colour video of the take (the studio films it on request), a monocular estimator's input.
            "video": VarSpec(("frame", "y", "x", "rgb"), "uint8", required=False,
                             description="one still camera's colour frames of the take"),
        },
        required_attrs={"fps": float},
        frame_chunk=64,
        description="unlabelled or labelled optical marker trajectories (C3D, TRC) on the shared axes",
    )
)

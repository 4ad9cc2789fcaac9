"""Schemas of the motion capture stage (DeepMoCap §3.5): the calibrated template, the solved poses, and the body
fitted to the reflectors (the default poses)."""

from __future__ import annotations

from mocapflow.schemas import ArtifactSchema, VarSpec, register_schema

SKELETON = register_schema(ArtifactSchema(
    name="skeleton",
    version=1,
    coords={"joint": VarSpec(("joint",), "str"), "reflector": VarSpec(("reflector",), "str"),
            "xyz": VarSpec(("xyz",), "str")},
    variables={
        "offset": VarSpec(("joint", "xyz"), "float32", "m", description="rest offset from the parent joint"),
        "bone_length": VarSpec(("joint",), "float32", "m", description="length of the offset"),
        "scale": VarSpec(("joint",), "float32",
                         description="scale of the template joint's offset: its segment's fitted scale "
                                     "(the coarse scale when scale_rounds is 0)"),
        "parent": VarSpec(("joint",), "int16", description="parent joint index, -1 for the root"),
        "level": VarSpec(("joint",), "int8", description="hierarchy level L0-L6 (Figure 9a)"),
        "bone": VarSpec(("reflector",), "int16", description="joint whose frame carries the reflector"),
        "reflector_offset": VarSpec(("reflector", "xyz"), "float32", "m", description="position in that frame"),
    },
    required_attrs={"length_unit": str, "up_axis": str},
    description="template skeleton calibrated to one sequence's optical data (Eq. 11)",
))

POSES = register_schema(ArtifactSchema(
    name="poses",
    version=1,
    coords={"frame": VarSpec(("frame",), "int64"), "joint": VarSpec(("joint",), "str"),
            "xyz": VarSpec(("xyz",), "str"), "quat": VarSpec(("quat",), "str")},
    variables={
        "position": VarSpec(("frame", "joint", "xyz"), "float32", "m", description="joint world position, NaN if unsolved"),
        "rotation": VarSpec(("frame", "joint", "quat"), "float32", "",
                            description="local rotation relative to the parent, quaternion x y z w"),
        "offset": VarSpec(("joint", "xyz"), "float32", "m", description="rest offset from the parent (fixed)"),
        "rms_error": VarSpec(("frame",), "float32", "m", description="RMS distance of fitted to seen reflectors"),
        "reflectors": VarSpec(("frame",), "int16", description="reflectors the frame was solved with"),
    },
    required_attrs={"length_unit": str, "up_axis": str, "fps": float},
    frame_chunk=64,
    description="articulated poses solved per frame on the calibrated template (40 DoF)",
))

BODY_POSES = register_schema(ArtifactSchema(
    name="body_poses",
    version=1,
    coords={"frame": VarSpec(("frame",), "int64"), "joint": VarSpec(("joint",), "str"),
            "bone": VarSpec(("bone",), "str"), "reflector": VarSpec(("reflector",), "str"),
            "xyz": VarSpec(("xyz",), "str"), "quat": VarSpec(("quat",), "str"),
            "phenotype": VarSpec(("phenotype",), "str")},
    variables={
        "position": VarSpec(("frame", "joint", "xyz"), "float32", "m",
                            description="the 20 template joints read from the fitted body (the bones' heads there)"),
        "bone_rotation": VarSpec(("frame", "bone", "quat"), "float64", "",
                                 description="every Anny bone's world rotation from its rest orientation, x y z w"),
        "root": VarSpec(("frame", "xyz"), "float64", "m", description="the root bone's head"),
        "reflector_position": VarSpec(("frame", "reflector", "xyz"), "float32", "m",
                                      description="where the fitted body puts each reflector"),
        "rms_error": VarSpec(("frame",), "float32", "m", description="RMS distance of the fitted to the seen reflectors"),
        "reflectors": VarSpec(("frame",), "int16", description="reflectors the frame was fitted with"),
        "fitted": VarSpec(("frame",), "bool", description="fitted to its own reflectors (False: its neighbours' pose)"),
        "shape": VarSpec(("phenotype",), "float64", description="Anny's phenotype fitted to the take"),
    },
    required_attrs={"length_unit": str, "up_axis": str, "fps": float},
    frame_chunk=64,
    description="Anny fitted to the labelled reflectors, the shape calibrated per take; joints read from the body",
))

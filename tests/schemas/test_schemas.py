"""Artifact schemas: what validate() accepts and refuses, chunk shapes, the registry and its unknown-name error."""

from __future__ import annotations

import numpy as np
import pytest
import xarray as xr

from mocapflow.schemas import (SCHEMAS, ArtifactSchema, SchemaViolation, UnknownSchema, VarSpec, get_schema,
                               register_schema)

SCHEMA = ArtifactSchema(
    name="probe",
    version=3,
    coords={"view": VarSpec(("view",), "str"), "frame": VarSpec(("frame",), "int64")},
    variables={
        "depth": VarSpec(("view", "frame", "y", "x"), "uint16", "mm"),
        "position": VarSpec(("frame", "reflector", "xyz"), "float32", "m"),
        "extra": VarSpec(("frame",), "float64", required=False),
    },
    required_attrs={"fps": float, "name": str, "count": int, "order": list},
    frame_chunk=4,
)


def conforming() -> xr.Dataset:
    return xr.Dataset(
        {"depth": (("view", "frame", "y", "x"), np.zeros((2, 6, 3, 5), np.uint16)),
         "position": (("frame", "reflector", "xyz"), np.zeros((6, 4, 3), np.float32))},
        coords={"view": np.array(["k0", "k1"], dtype=object), "frame": np.arange(6, dtype=np.int64)},
        attrs={"fps": 30, "name": "take", "count": np.int64(2), "order": ("a", "b")})


def problems(ds: xr.Dataset) -> str:
    with pytest.raises(SchemaViolation) as err:
        SCHEMA.validate(ds)
    return str(err.value)


def test_a_conforming_dataset_passes_with_or_without_its_optional_variable():
    SCHEMA.validate(conforming())  # an int fps is a float, a numpy int an int, a tuple a list
    SCHEMA.validate(conforming().assign(extra=("frame", np.arange(6, dtype=np.float64))))
    SCHEMA.validate(conforming().assign_coords(view=np.array(["k0", "k1"])))  # fixed-width unicode is a str too


def test_wrong_dims_are_refused():
    ds = conforming()
    ds["depth"] = ds["depth"].transpose("frame", "view", "y", "x")
    assert problems(ds) == ("probe v3: 'depth' has dims ('frame', 'view', 'y', 'x'), "
                            "expected ('view', 'frame', 'y', 'x')")


def test_a_wrong_dtype_is_refused_also_for_an_optional_variable():
    ds = conforming()
    ds["position"] = ds["position"].astype(np.float64)
    assert problems(ds) == "probe v3: 'position' has dtype float64, expected float32"
    assert problems(conforming().assign(extra=("frame", np.arange(6, dtype=np.int32)))) == \
        "probe v3: 'extra' has dtype int32, expected float64"


def test_a_missing_required_variable_or_coordinate_is_refused():
    assert problems(conforming().drop_vars("position")) == "probe v3: missing variable 'position' ('frame', 'reflector', 'xyz')"
    assert problems(conforming().drop_vars("view")) == "probe v3: missing variable 'view' ('view',)"


def test_a_missing_or_mistyped_attribute_is_refused():
    ds = conforming()
    del ds.attrs["fps"]
    assert problems(ds) == "probe v3: missing attribute 'fps' (float)"
    ds = conforming()
    ds.attrs["count"] = 2.0
    assert problems(ds) == "probe v3: attribute 'count' is float, expected int"


def test_every_problem_is_listed_at_once():
    ds = conforming().drop_vars("position")
    ds["depth"] = ds["depth"].astype(np.int32)
    ds.attrs.pop("name")
    assert problems(ds) == ("probe v3: 'depth' has dtype int32, expected uint16; missing variable 'position' "
                            "('frame', 'reflector', 'xyz'); missing attribute 'name' (str)")


def test_chunks_cut_frames_by_frame_chunk_views_by_one_and_keep_other_dims_whole():
    assert SCHEMA.chunks("depth", (2, 10, 424, 512), ("view", "frame", "y", "x")) == (1, 4, 424, 512)
    assert SCHEMA.chunks("depth", (2, 3, 424, 512), ("view", "frame", "y", "x")) == (1, 3, 424, 512)  # short take
    assert SCHEMA.chunks("position", (0, 26, 3), ("frame", "reflector", "xyz")) == (1, 26, 3)  # never a 0 chunk
    assert get_schema("markers3d").chunks("position", (300, 26, 3), ("frame", "reflector", "xyz")) == (64, 26, 3)


def test_an_unknown_schema_name_is_a_lookup_error_naming_it_a_close_match_and_the_registered_ones():
    with pytest.raises(UnknownSchema) as err:
        get_schema("markers3")
    message = str(err.value)
    assert message.startswith("unknown schema 'markers3' (did you mean 'markers3d'?); registered schemas: [")
    assert "'markers3d', 'poses', 'raw_markers', 'raw_sequence'" in message and "register_schema" in message
    assert isinstance(err.value, LookupError) and not isinstance(err.value, KeyError)
    assert err.value.name == "markers3" and "raw_sequence" in err.value.registered
    with pytest.raises(UnknownSchema, match=r"^unknown schema 'zzz'; registered schemas: \["):  # nothing close
        get_schema("zzz")


def test_a_registered_schema_is_found_by_name_and_replaced_by_a_later_registration():
    name = "probe_registered"
    assert name not in SCHEMAS
    try:
        first = register_schema(ArtifactSchema(name, 1, {"v": VarSpec(("frame",), "float32")}))
        assert get_schema(name) is first
        second = register_schema(ArtifactSchema(name, 2, {"v": VarSpec(("frame",), "float64")}))
        assert get_schema(name) is second and get_schema(name).version == 2
    finally:
        SCHEMAS.pop(name, None)
    with pytest.raises(UnknownSchema):
        get_schema(name)


def test_the_builtin_schemas_are_registered_under_their_own_names():
    for name in ("raw_sequence", "reflector_masks", "scene_flow", "reflectors2d", "markers3d", "smoothed_markers",
                 "poses", "fcn_weights"):
        assert get_schema(name).name == name

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

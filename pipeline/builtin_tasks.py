"""Registrations of the built-in stage implementations (see registry.py)."""

from __future__ import annotations

from mocapflow.pipeline.registry import NoParams, TaskSpec, register

# The `frames` stage: every raw sequence of a dataset synthesized (studio) or imported
# (zarr, image folders) into the raw-sequence schema. The dataset reader runs it.
register(
    TaskSpec(
        name="ingest",
        fn=None,
        version="1",
        params=NoParams,
        output="raw_sequence",
        partition="sequence",
        source=True,
        description="synthesize or import a dataset's sequences into the raw-sequence schema",
    )
)

"""The masks and flow stages through the engine: region-by-region equals whole, swapping recomputes flow only."""

from __future__ import annotations

import numpy as np

from conftest import last_json, mocapflow, plane_sequence, read_artifacts

CATALOG = """\
storage: {{root: {root}, region_frames: {region}}}
datasets:
  rec: {{kind: zarr, path: data}}
stages:
  frames: {{task: ingest}}
  masks: {{task: reflector_mask, inputs: [frames]}}
  flow: {{task: dis, inputs: [frames]}}
"""


def write_plane(path, frames=20):
    steps = [np.array([0.004 * np.sin(k / 3), 0.003, 0.002 * np.cos(k / 4)]) for k in range(frames - 1)]
    plane_sequence(steps).to_zarr(path, zarr_format=3, consolidated=False, mode="w")


def by_partition(root):
    return {pid: arrays for (pid, _), arrays in read_artifacts(root).items()}


def test_regions_recompute_alone_and_swap_touches_flow_only(tmp_path):
    write_plane(tmp_path / "data" / "plane.zarr", frames=17)
    (tmp_path / "catalog.yaml").write_text(CATALOG.format(root="regions/", region=8))
    first = last_json(mocapflow("run", "--json", cwd=tmp_path))
    assert first["regions"]["flow/plane/cam"] == 3  # frames 0-7, 8-15, 16, each with its halo frame
    (tmp_path / "catalog.yaml").write_text(CATALOG.format(root="whole/", region=32))
    mocapflow("run", "--json", cwd=tmp_path)
    regions, whole = by_partition(tmp_path / "regions"), by_partition(tmp_path / "whole")
    for var in ("flow", "valid", "colorized_flow"):
        np.testing.assert_array_equal(regions["flow/plane/cam"][var], whole["flow/plane/cam"][var])
    assert regions["flow/plane/cam"]["valid"][0, 8].mean() > 0.5  # a region's first frame used its halo
    swapped = last_json(mocapflow("run", "--json", "--set", "stages.flow.task=primal_dual", "--set",
                                  "stages.flow.params.device=cpu", cwd=tmp_path))
    assert swapped["executed"] == ["flow/plane/cam"]
    assert sorted(swapped["cached"]) == ["frames/plane", "masks/plane/cam"]

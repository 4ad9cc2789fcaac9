"""A per-dataset stage's inputs (pipeline/samples.py): streamed samples read from storage are the samples loaded
whole, one view-frame at a time."""

import numpy as np
import pytest

from conftest import mocapflow
from mocapflow.pipeline.catalog import load_catalog
from mocapflow.pipeline.plan import build_plan
from mocapflow.pipeline.samples import StoredSamples, load_samples, samples_input
from mocapflow.pipeline.storage import Store
from test_training import CATALOG


def test_streamed_samples_are_the_loaded_ones_read_one_at_a_time(tmp_path):
    (tmp_path / "catalog.yaml").write_text(CATALOG)
    mocapflow("run", "--catalog", "catalog.yaml", "--until", "samples", cwd=tmp_path, timeout=600)
    catalog = load_catalog(tmp_path / "catalog.yaml", ())
    store, item = Store(catalog.root), build_plan(catalog).items["weights/train"]
    up = item.upstream["samples"]
    whole = load_samples(store, up)
    streamed = samples_input(store, up, None, ("depth_image", "flow_image"))
    assert isinstance(streamed, StoredSamples) and len(streamed) == whole.sizes["sample"] == 2 * 2 * 6
    assert "depth_image" not in streamed.table and set(streamed.table.data_vars) == {"box", "gt_uv", "gt_uv_prev",
                                                                                      "gt_pixels"}
    for name in ("frame", "view", "sequence", "gt_uv", "box"):
        np.testing.assert_array_equal(streamed.table[name].values, whole[name].values)
    for index in (0, 5, 6, 13, 23):  # across views and sequences
        images = streamed.read(index, ("depth_image", "flow_image"))
        np.testing.assert_array_equal(images["depth_image"], whole["depth_image"].values[index])
        np.testing.assert_array_equal(images["flow_image"], whole["flow_image"].values[index])
    assert whole["depth_image"].values[0].any() and not np.array_equal(whole["depth_image"].values[0],
                                                                       whole["depth_image"].values[13])
    with pytest.raises(IndexError, match="sample 24 of 24"):
        streamed.read(24, ("depth_image",))

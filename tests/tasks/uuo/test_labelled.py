"""Labelled recordings around UUO: fragments of one label joined, ghosts dropped, labels hidden in file order."""

from __future__ import annotations

import numpy as np
import pytest
import xarray as xr

from mocapflow.tasks.uuo import labelled


def _markers(positions, labels):
    n = positions.shape[0]
    return xr.Dataset({"position": (("frame", "marker", "xyz"), positions.astype(np.float32)),
                       "timestamp": (("frame",), np.arange(n) / 100.0),
                       "label": (("marker",), np.array(labels, dtype=object))},
                      coords={"frame": np.arange(n), "marker": np.array([f"t{i}" for i in range(len(labels))],
                                                                        dtype=object)},
                      attrs={"fps": 100.0})


def test_fragments_of_a_label_are_joined_and_unlabelled_trajectories_dropped():
    nan = np.nan
    p = np.full((4, 4, 3), nan)
    p[0:2, 0] = [[1, 0, 0], [1, 0, 1]]  # LASI, first fragment (frames 0-1)
    p[2:4, 2] = [[1, 0, 2], [1, 0, 3]]  # LASI again, under a new trajectory (frames 2-3)
    p[:, 1] = 5.0  # a ghost without a label
    p[:, 3] = 7.0  # RASI, with a subject prefix
    out = labelled.merge_labels(_markers(p, ["Sub:LASI", "", "LASI", "Sub:RASI"]), labelled.MergeLabelsConfig())
    assert list(out.marker.values) == ["LASI", "RASI"] and list(out.label.values) == ["LASI", "RASI"]
    np.testing.assert_array_equal(out.position.values[:, 0, 2], [0, 1, 2, 3])
    assert (out.position.values[:, 1] == 7.0).all() and out.attrs["merged_from"] == 4


def test_labels_are_hidden_in_file_order_and_a_take_without_labels_is_refused():
    p = np.arange(2 * 3 * 3, dtype=float).reshape(2, 3, 3)
    out = labelled.drop_labels(_markers(p, ["A", "B", "A"]), labelled.DropLabelsConfig())
    assert list(out.marker.values) == ["m000", "m001", "m002"] and "label" not in out
    np.testing.assert_array_equal(out.position.values, p.astype(np.float32))
    with pytest.raises(labelled.LabelError, match="labels: use"):
        labelled.merge_labels(_markers(p, ["A", "B", "A"]).drop_vars("label"), labelled.MergeLabelsConfig())
    with pytest.raises(labelled.LabelError, match="no trajectory has a marker label"):
        labelled.merge_labels(_markers(p, ["", "*1", "unlabelled2"]), labelled.MergeLabelsConfig())

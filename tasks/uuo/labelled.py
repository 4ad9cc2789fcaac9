"""Labelled recordings around UUO: the labelled reference of a recorded take, and its labels hidden from the solver.

UUO's paper compares its unlabelled solve with the same body fit on the labelled markers (Milef et al. 2024,
Table 2, "labelled markers"). On a recorded take the file's labels give which trajectories are one marker:
``merge_labels`` joins the fragments of each label into one trajectory (a marker lost and found again under a new
trajectory id) and drops the trajectories without a label (ghosts, unidentified points); the same solver then
gives the reference. ``drop_labels`` hides the labels (trajectories m000, m001, ... in the file's order), so the
unlabelled solve sees only positions while the evaluation can still tell each trajectory's label by its index.
"""

from __future__ import annotations

import fnmatch
from dataclasses import dataclass

import numpy as np
import xarray as xr


class LabelError(ValueError):
    """Markers whose labels cannot be used."""


@dataclass(frozen=True)
class MergeLabelsConfig:
    # labels that name no marker (fnmatch patterns): empty, a reader's placeholder, a system's unlabelled points
    unlabelled: tuple[str, ...] = ("", "unlabelled*", "unlabeled*", "Unlabeled*", "[*]*")
    drop_prefix: bool = True  # "Subject:LASI" -> "LASI" (a Vicon subject prefix)


@dataclass(frozen=True)
class DropLabelsConfig:
    pass


def base_label(label: str, drop_prefix: bool = True) -> str:
    """A file label without its subject prefix (``Derrick:C7`` -> ``C7``) and surrounding blanks."""
    label = str(label).strip()
    return label.rsplit(":", 1)[-1].strip() if drop_prefix else label


def _labels(markers: xr.Dataset) -> list[str]:
    if "label" not in markers:
        raise LabelError("the markers carry no file labels; read the recording with labels: use")
    return [str(label) for label in markers["label"].values]


def merge_labels(markers: xr.Dataset, config: MergeLabelsConfig) -> xr.Dataset:
    """Stage ``labelled``: one trajectory per label (its fragments joined, the first seen sample where two
    overlap), unlabelled trajectories dropped.  position (frame, marker, xyz) -> (frame, label, xyz)"""
    labels = [base_label(label, config.drop_prefix) for label in _labels(markers)]
    named = [label for label in labels
             if not any(fnmatch.fnmatchcase(label, pattern) for pattern in config.unlabelled)]
    if not named:
        raise LabelError(f"no trajectory has a marker label (labels {sorted(set(labels))} all match the unlabelled "
                         f"patterns {list(config.unlabelled)}); a labelled reference needs labelled markers")
    order = list(dict.fromkeys(named))  # first appearance in the file
    positions = markers["position"].transpose("frame", "marker", "xyz").values
    merged = np.full((positions.shape[0], len(order), 3), np.nan, np.float32)
    for k, label in enumerate(order):
        for i in (i for i, name in enumerate(labels) if name == label):  # file order: earlier fragments win
            free = ~np.isfinite(merged[:, k]).all(-1) & np.isfinite(positions[:, i]).all(-1)
            merged[free, k] = positions[free, i]
    return xr.Dataset(
        {"position": (("frame", "marker", "xyz"), merged), "timestamp": markers["timestamp"],
         "label": (("marker",), np.array(order, dtype=object))},
        coords={"frame": markers["frame"].values, "marker": np.array(order, dtype=object),
                "xyz": np.array(["x", "y", "z"], dtype=object)},
        attrs={**markers.attrs, "merged_from": len(labels)})


def drop_labels(markers: xr.Dataset, config: DropLabelsConfig) -> xr.Dataset:
    """Stage ``unlabelled``: the same trajectories as m000, m001, ... (file order), with no label."""
    n = markers.sizes["marker"]
    return xr.Dataset(
        {"position": markers["position"].transpose("frame", "marker", "xyz").variable,
         "timestamp": markers["timestamp"]},
        coords={"frame": markers["frame"].values, "marker": np.array([f"m{i:03d}" for i in range(n)], dtype=object),
                "xyz": np.array(["x", "y", "z"], dtype=object)},
        attrs=dict(markers.attrs))

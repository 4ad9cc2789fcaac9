"""Trained weights shipped with mocapflow.

``deepmocap_fcn.pt``: the default two-stream FCN of the `heatmaps` stage (plain tensors, read with
``torch.load(..., weights_only=True)``), chosen by the rule of docs/deepmocap.md on the realistic validation split:
trained on the mesh body with real-sized reflector regions (``training/catalog_mesh_tune.yaml``, continued by
``training/catalog_mesh_long.yaml``); a stage whose ``weights`` parameter is empty uses it.
``deepmocap_fcn_capsule.pt``: the first network, trained on the capsule body with small regions
(``training/catalog.yaml``), kept as a named option: ``heatmaps: {params: {weights: .../deepmocap_fcn_capsule.pt}}``.
"""

from importlib import resources
from pathlib import Path


def packaged(name: str) -> Path:
    """Path of a weights file shipped in this package."""
    return Path(str(resources.files(__name__) / name))

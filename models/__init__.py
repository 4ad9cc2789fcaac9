"""Trained weights shipped with mocapflow.

``deepmocap_fcn.pt``: the two-stream FCN of the `heatmaps` stage (plain tensors, read with
``torch.load(..., weights_only=True)``), trained on studio data by ``mocapflow train`` from
``training/catalog.yaml``; a stage whose ``weights`` parameter is empty uses it.
``deepmocap_fcn_mesh_large.pt``: the same network fine-tuned on the mesh body with real-sized reflector regions
(``training/catalog_mesh_tune.yaml``); not the default (docs/deepmocap.md, "A network for the realistic studio"):
``heatmaps: {params: {weights: .../deepmocap_fcn_mesh_large.pt}}``.
"""

from importlib import resources
from pathlib import Path


def packaged(name: str) -> Path:
    """Path of a weights file shipped in this package."""
    return Path(str(resources.files(__name__) / name))

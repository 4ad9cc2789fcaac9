"""Trained weights shipped with mocapflow.

``deepmocap_fcn.pt``: the default two-stream FCN of the `heatmaps` stage (plain tensors, read with
``torch.load(..., weights_only=True)``), chosen by the rule of docs/deepmocap.md on the realistic validation split:
trained on the mesh body with real-sized reflector regions (``training/catalog_mesh_tune.yaml``, continued by
``training/catalog_mesh_long.yaml``); a stage whose ``weights`` parameter is empty uses it.
``deepmocap_fcn_capsule.pt``: the first network, trained on the capsule body with small regions
(``training/catalog.yaml``), kept as a named option: ``heatmaps: {params: {weights: .../deepmocap_fcn_capsule.pt}}``.
``suit_cornerdet.pt``: the suit's CornerdetNet (``training/suit.yaml``, positives the readable corners).
``suit_codes.pt``: the suit's RejectorNet and RecogNet, trained on every coded square of ``training/suit_long.yaml``
from the former ones, chosen on a tuning split by ``benchmarks/suit_networks_tune.py`` (docs/suit.md).
``suit_cornerdet_visible.pt``: CornerdetNet trained on every visible corner (``training/suit_long.yaml``), not chosen
there; a named option: ``corners: {params: {weights: .../suit_cornerdet_visible.pt}}``.
"""

from importlib import resources
from pathlib import Path


def packaged(name: str) -> Path:
    """Path of a weights file shipped in this package."""
    return Path(str(resources.files(__name__) / name))

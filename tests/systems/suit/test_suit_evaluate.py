"""What `mocapflow evaluate` scores in a suit catalog: the exact and the perturbed triangulation, and the fillings
of random and of occlusion-shaped holes, each under its own key."""

from __future__ import annotations

from mocapflow.pipeline.catalog import load_catalog
from mocapflow.systems.suit.evaluate import suit_stages

CATALOG = """\
data_roots: [.]
storage: {root: storage/}
datasets:
  suits: {kind: studio_suit, suit: small, defaults: {frames: 3}, sequences: {sq: {motion: classic_squat, seed: 1}}}
stages:
  images: {task: ingest_suit, dataset: suits}
  labels: {task: oracle_labels, inputs: [images]}
  points: {task: triangulate_corners, inputs: {labels: labels, images: images}}
  shifted: {task: triangulate_corners, inputs: {labels: labels, images: images}, params: {calibration_error_px: 0.25}}
  hidden: {task: hide_corners, inputs: [points]}
  occluded: {task: hide_corners, inputs: [points], params: {shape: patch}}
  filled: {task: fill_suit, inputs: {points: points, images: images}}
  filled_shifted: {task: fill_suit, inputs: {points: shifted, images: images}}
  filled_hidden: {task: fill_suit, inputs: {points: hidden, images: images}}
  filled_occluded: {task: fill_suit, inputs: {points: occluded, images: images}}
"""


def test_each_triangulation_and_filling_is_scored_under_its_own_key(tmp_path):
    (tmp_path / "catalog.yaml").write_text(CATALOG)
    stages = suit_stages(load_catalog(tmp_path / "catalog.yaml"))
    assert stages == {"suit_images": "images", "suit_labels": "labels", "suit_points": "points",
                      "suit_points_perturbed": "shifted", "suit_filled": "filled", "suit_filled_hidden": "filled_hidden",
                      "suit_filled_occluded": "filled_occluded"}


def test_grown_labels_are_scored_and_the_labels_as_read_beside_them(tmp_path):
    chain = CATALOG.replace("  labels: {task: oracle_labels, inputs: [images]}\n", """\
  corners: {task: find_corners, inputs: [images]}
  quads: {task: find_quads, inputs: {images: images, corners: corners}}
  codes: {task: read_codes, inputs: {images: images, corners: corners, quads: quads}}
  read: {task: label_corners, inputs: {images: images, corners: corners, quads: quads, codes: codes}}
  labels: {task: grow_labels, inputs: {images: images, corners: corners, labels: read}}
""")
    (tmp_path / "catalog.yaml").write_text(chain)
    stages = suit_stages(load_catalog(tmp_path / "catalog.yaml"))
    assert stages["suit_labels"] == "labels" and stages["suit_labels_read"] == "read"
    assert stages["suit_corners"] == "corners" and stages["suit_codes"] == "codes"

"""The checkerboard suit's task specs (Chen, Park, Macit, Kavan 2021): tasks/suit."""

from __future__ import annotations

from mocapflow.pipeline.registry import Lazy, NoParams, TaskSpec
from mocapflow.tasks.shared.cameras import CALIBRATION_VARIABLES as CALIBRATION
from mocapflow.tasks.suit import training as suit_training
from mocapflow.tasks.suit.codes import ReadCodesConfig
from mocapflow.tasks.suit.corners import FindCornersConfig
from mocapflow.tasks.suit.fill import FillDetectionsConfig, FillSuitConfig
from mocapflow.tasks.suit.grow import GrowConfig
from mocapflow.tasks.suit.holdout import HoldoutConfig
from mocapflow.tasks.suit.labels import LabelConfig
from mocapflow.tasks.suit.oracle import OracleConfig
from mocapflow.tasks.suit.quads import QuadConfig
from mocapflow.tasks.suit.reconstruct import ReconstructConfig
from mocapflow.tasks.suit.verify import VerifyCodesConfig, VerifyLabelsConfig

TASKS = (
    # The suit's counterpart: a `studio_suit` dataset's takes as grey images with calibration and the pattern.
    TaskSpec(
        name="ingest_suit",
        fn=None,
        version="1",
        params=NoParams,
        output="suit_images",
        partition="sequence",
        source=True,
        description="film or import a dataset's checkerboard-suit takes: grey images, calibration, the suit's pattern",
    ),

    # The suit's 2D chain (Chen et al. 2021, §3.1-3.2): corners, candidate quads, their codes, labelled corners.
    TaskSpec(
        name="find_corners", fn=Lazy("mocapflow.tasks.suit.corners", "find_corners"), version="1",
        params=FindCornersConfig, output="suit_corners", partition="view",
        inputs={"images": "suit_images"}, reads={"images": ("image",)},
        weights_params=("weights",), packaged_weights={"weights": "suit_cornerdet.pt"},
        description="CornerdetNet on every cell with contrast, clustered and refined on re-crops (§3.1)",
    ),
    TaskSpec(
        name="find_quads", fn=Lazy("mocapflow.tasks.suit.quads", "find_quads"), version="1",
        params=QuadConfig, output="suit_quads", partition="view",
        inputs={"images": "suit_images", "corners": "suit_corners"}, reads={"images": ("image",), "corners": ("x", "y")},
        description="candidate quads: convex 4-sets of detections, angles 45-135 degrees, white inside (§3.2)",
    ),
    TaskSpec(
        name="read_codes", fn=Lazy("mocapflow.tasks.suit.codes", "read_codes"), version="1",
        params=ReadCodesConfig, output="suit_codes", partition="view",
        inputs={"images": "suit_images", "corners": "suit_corners", "quads": "suit_quads"},
        reads={"images": ("image",), "corners": ("x", "y")},
        weights_params=("weights",), packaged_weights={"weights": "suit_codes.pt"},
        description="each candidate warped to 104 x 104; RejectorNet accepts, RecogNet reads code and rotation (§3.2)",
    ),
    TaskSpec(
        name="label_corners", fn=Lazy("mocapflow.tasks.suit.labels", "label_corners"), version="1",
        params=LabelConfig, output="suit_labels", partition="view",
        inputs={"images": "suit_images", "corners": "suit_corners", "quads": "suit_quads", "codes": "suit_codes"},
        reads={"images": ("code", "square_corners", "corner_face"), "corners": ("x", "y")},
        description="corner identities from the accepted quads, kept where every quad naming a corner agrees (§3.2)",
    ),
    TaskSpec(
        name="grow_labels", fn=Lazy("mocapflow.tasks.suit.grow", "grow_corner_labels"), version="1",
        params=GrowConfig, output="suit_labels", partition="view",
        inputs={"images": "suit_images", "corners": "suit_corners", "labels": "suit_labels"},
        reads={"images": ("cells",), "corners": ("x", "y", "logit")},
        description="labels grown over the suit's grid: unread squares' corners completed and extended from "
                    "labelled ones (beyond the paper)",
    ),
    # Every reading checked against the print (beyond the paper): each stage writes the schema it checks, so a
    # catalog inserts it after read_codes or grow_labels (benchmarks/suit_verify.yaml) and the rest reads it as is.
    TaskSpec(
        name="verify_codes", fn=Lazy("mocapflow.tasks.suit.verify", "verify_codes"), version="1",
        params=VerifyCodesConfig, output="suit_codes", partition="view",
        inputs={"images": "suit_images", "corners": "suit_corners", "quads": "suit_quads", "codes": "suit_codes"},
        reads={"images": ("image", "code"), "corners": ("x", "y")},
        description="each accepted quad rectified and compared with the print's glyph pairs in four rotations "
                    "(NCC): the reading kept where the print agrees, replaced where the print is decisive, else "
                    "refused",
    ),
    TaskSpec(
        name="verify_labels", fn=Lazy("mocapflow.tasks.suit.verify", "verify_labels"), version="1",
        params=VerifyLabelsConfig, output="suit_labels", partition="view",
        inputs={"images": "suit_images", "labels": "suit_labels"},
        reads={"images": ("image", "code", "square_corners", "cells")},
        description="grown labels (or all) kept only where the print's squares around the corner match the image "
                    "there (NCC) and put the corner at the label",
    ),
    # Training the chain from studio takes (§4): per-image samples, then one training per dataset.
    TaskSpec(
        name="corner_training_samples", fn=suit_training.corner_training_samples, version="1",
        params=suit_training.CornerSampleStageConfig, output="suit_corner_samples", partition="view",
        inputs={"images": "suit_images"}, reads={"images": ("image", "gt_corners2d", "gt_visible", "gt_readable")},
        description="CornerdetNet's 20 x 20 training crops of studio images, from the truth (§4.1)",
    ),
    TaskSpec(
        name="train_cornerdet", fn=suit_training.train_cornerdet_stage, version="2",
        params=suit_training.TrainCornerdetConfig, output="suit_net_weights", partition="dataset",
        inputs={"samples": "suit_corner_samples"}, streams={"samples": ("crops",)}, checkpoints=True,
        weights_params=("init",),
        description="train CornerdetNet (seeded; crops streamed through a pool of images; resumable from its "
                    "checkpoint)",
    ),
    TaskSpec(
        name="quad_training_samples", fn=suit_training.quad_training_samples, version="1",
        params=suit_training.QuadSampleStageConfig, output="suit_quad_samples", partition="view",
        inputs={"images": "suit_images", "corners": "suit_corners", "quads": "suit_quads"},
        reads={"images": ("image", "code", "square_corners", "gt_corners2d", "gt_visible"), "corners": ("x", "y")},
        description="the chain's candidate quads of studio images, labelled from the truth (§4.2)",
    ),
    TaskSpec(
        name="train_codes", fn=suit_training.train_codes_stage, version="2",
        params=suit_training.TrainCodesConfig, output="suit_net_weights", partition="dataset",
        inputs={"samples": "suit_quad_samples"}, streams={"samples": ("crops",)}, checkpoints=True,
        weights_params=("init",),
        description="train RejectorNet and RecogNet on studio quads and synthetic crops of every code (seeded; "
                    "crops streamed through a pool of images; resumable from its checkpoint)",
    ),

    TaskSpec(
        name="oracle_labels", fn=Lazy("mocapflow.tasks.suit.oracle", "oracle_labels"), version="1",
        params=OracleConfig, output="suit_labels", partition="view",
        inputs={"images": "suit_images"}, reads={"images": ("gt_corners2d", "gt_readable")},
        description="suit labels from the studio's truth plus noise: the 3D stages on perfect 2D (not the 2D chain)",
    ),
    TaskSpec(
        name="triangulate_corners", fn=Lazy("mocapflow.tasks.suit.reconstruct", "triangulate_corners"), version="3",
        params=ReconstructConfig, output="suit_points",
        partition="sequence", inputs={"labels": "suit_labels", "images": "suit_images"},
        reads={"labels": ("x", "y", "quads"), "images": CALIBRATION},
        description="labelled corners triangulated from every claiming view, outlier views dropped (Chen et al. §3.3)",
    ),
    TaskSpec(
        name="fill_suit", fn=Lazy("mocapflow.tasks.suit.fill", "fill_suit"), version="1", params=FillSuitConfig,
        output="suit_filled", partition="sequence", whole_sequence=True,
        inputs={"points": "suit_points", "images": "suit_images"},
        reads={"points": ("position",), "images": ("corner_face", "corner_bary", "cells")},
        description="the body fitted to the observed corners, their displacements filled by Eq. 8 and reposed (§5)",
    ),
    TaskSpec(
        name="fill_suit_detections", fn=Lazy("mocapflow.tasks.suit.fill", "fill_suit_detections"), version="1",
        params=FillDetectionsConfig, output="suit_filled", partition="sequence", whole_sequence=True,
        inputs={"points": "suit_points", "images": "suit_images", "corners": "suit_corners", "labels": "suit_labels"},
        reads={"points": ("position",), "images": ("corner_face", "corner_bary", "cells") + CALIBRATION,
               "corners": ("x", "y"), "labels": ("x", "y")},
        description="fill_suit with the limbs no observed corner holds turned onto the corner detections no label "
                    "claims, their corners triangulated there and the body fitted again (beyond the paper)",
    ),
    TaskSpec(
        name="hide_corners", fn=Lazy("mocapflow.tasks.suit.holdout", "hide_corners"), version="1",
        params=HoldoutConfig, output="suit_points", partition="sequence",
        whole_sequence=True, inputs={"points": "suit_points"},
        description="hide a seeded share of observed corners for runs of frames, to score the hole filling",
    ),
    )

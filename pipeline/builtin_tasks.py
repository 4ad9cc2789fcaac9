"""Registrations of the built-in stage implementations (see registry.py)."""

from __future__ import annotations

from mocapflow.pipeline.registry import Lazy, NoParams, TaskSpec, register
from mocapflow.tasks.deepmocap import (flow, markers3d, masks, plausibility, poses, refine2d, reflectors2d, skeleton,
                                       smoothing, training)
from mocapflow.tasks.deepmocap.heatmaps import HeatmapConfig
from mocapflow.tasks.shared.cameras import CALIBRATION_VARIABLES as CALIBRATION
from mocapflow.tasks.suit.codes import ReadCodesConfig
from mocapflow.tasks.suit.corners import FindCornersConfig
from mocapflow.tasks.suit.fill import FillSuitConfig
from mocapflow.tasks.suit.holdout import HoldoutConfig
from mocapflow.tasks.suit.labels import LabelConfig
from mocapflow.tasks.suit.oracle import OracleConfig
from mocapflow.tasks.suit.quads import QuadConfig
from mocapflow.tasks.suit.reconstruct import ReconstructConfig
from mocapflow.tasks.suit import training as suit_training
from mocapflow.tasks.uuo import labelled, prior, segmentation, solve


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

# The marker-file counterpart: a `markers` dataset's C3D or TRC recordings as raw_markers (frame, marker, xyz).
register(
    TaskSpec(
        name="ingest_markers",
        fn=None,
        version="1",
        params=NoParams,
        output="raw_markers",
        partition="sequence",
        source=True,
        description="import a dataset's marker recordings (C3D, TRC) as trajectories in metres, Z up",
    )
)

# The suit's counterpart: a `studio_suit` dataset's takes as grey images with calibration and the pattern.
register(
    TaskSpec(
        name="ingest_suit",
        fn=None,
        version="1",
        params=NoParams,
        output="suit_images",
        partition="sequence",
        source=True,
        description="film or import a dataset's checkerboard-suit takes: grey images, calibration, the suit's pattern",
    )
)

# The suit's 2D chain (Chen et al. 2021, §3.1-3.2): corners, candidate quads, their codes, labelled corners.
register(TaskSpec(
    name="find_corners", fn=Lazy("mocapflow.tasks.suit.corners", "find_corners"), version="1",
    params=FindCornersConfig, output="suit_corners", partition="view",
    inputs={"images": "suit_images"}, reads={"images": ("image",)},
    weights_params=("weights",), packaged_weights={"weights": "suit_cornerdet.pt"},
    description="CornerdetNet on every cell with contrast, clustered and refined on re-crops (§3.1)",
))
register(TaskSpec(
    name="find_quads", fn=Lazy("mocapflow.tasks.suit.quads", "find_quads"), version="1",
    params=QuadConfig, output="suit_quads", partition="view",
    inputs={"images": "suit_images", "corners": "suit_corners"}, reads={"images": ("image",), "corners": ("x", "y")},
    description="candidate quads: convex 4-sets of detections, angles 45-135 degrees, white inside (§3.2)",
))
register(TaskSpec(
    name="read_codes", fn=Lazy("mocapflow.tasks.suit.codes", "read_codes"), version="1",
    params=ReadCodesConfig, output="suit_codes", partition="view",
    inputs={"images": "suit_images", "corners": "suit_corners", "quads": "suit_quads"},
    reads={"images": ("image",), "corners": ("x", "y")},
    weights_params=("weights",), packaged_weights={"weights": "suit_codes.pt"},
    description="each candidate warped to 104 x 104; RejectorNet accepts, RecogNet reads code and rotation (§3.2)",
))
register(TaskSpec(
    name="label_corners", fn=Lazy("mocapflow.tasks.suit.labels", "label_corners"), version="1",
    params=LabelConfig, output="suit_labels", partition="view",
    inputs={"images": "suit_images", "corners": "suit_corners", "quads": "suit_quads", "codes": "suit_codes"},
    reads={"images": ("code", "square_corners", "corner_face"), "corners": ("x", "y")},
    description="corner identities from the accepted quads, kept where every quad naming a corner agrees (§3.2)",
))
# Training the chain from studio takes (§4): per-image samples, then one training per dataset.
register(TaskSpec(
    name="corner_training_samples", fn=suit_training.corner_training_samples, version="1",
    params=suit_training.CornerSampleStageConfig, output="suit_corner_samples", partition="view",
    inputs={"images": "suit_images"}, reads={"images": ("image", "gt_corners2d", "gt_visible", "gt_readable")},
    description="CornerdetNet's 20 x 20 training crops of studio images, from the truth (§4.1)",
))
register(TaskSpec(
    name="train_cornerdet", fn=suit_training.train_cornerdet_stage, version="1",
    params=suit_training.TrainCornerdetConfig, output="suit_net_weights", partition="dataset",
    inputs={"samples": "suit_corner_samples"}, description="train CornerdetNet (seeded)",
))
register(TaskSpec(
    name="quad_training_samples", fn=suit_training.quad_training_samples, version="1",
    params=suit_training.QuadSampleStageConfig, output="suit_quad_samples", partition="view",
    inputs={"images": "suit_images", "corners": "suit_corners", "quads": "suit_quads"},
    reads={"images": ("image", "code", "square_corners", "gt_corners2d", "gt_visible"), "corners": ("x", "y")},
    description="the chain's candidate quads of studio images, labelled from the truth (§4.2)",
))
register(TaskSpec(
    name="train_codes", fn=suit_training.train_codes_stage, version="1",
    params=suit_training.TrainCodesConfig, output="suit_net_weights", partition="dataset",
    inputs={"samples": "suit_quad_samples"},
    description="train RejectorNet and RecogNet on studio quads and synthetic crops of every code (seeded)",
))

register(TaskSpec(
    name="oracle_labels", fn=Lazy("mocapflow.tasks.suit.oracle", "oracle_labels"), version="1",
    params=OracleConfig, output="suit_labels", partition="view",
    inputs={"images": "suit_images"}, reads={"images": ("gt_corners2d", "gt_readable")},
    description="suit labels from the studio's truth plus noise: the 3D stages on perfect 2D (not the 2D chain)",
))
register(TaskSpec(
    name="triangulate_corners", fn=Lazy("mocapflow.tasks.suit.reconstruct", "triangulate_corners"), version="1",
    params=ReconstructConfig, output="suit_points",
    partition="sequence", inputs={"labels": "suit_labels", "images": "suit_images"},
    reads={"labels": ("x", "y"), "images": CALIBRATION},
    description="labelled corners triangulated from every claiming view, outlier views dropped (Chen et al. §3.3)",
))
register(TaskSpec(
    name="fill_suit", fn=Lazy("mocapflow.tasks.suit.fill", "fill_suit"), version="1", params=FillSuitConfig,
    output="suit_filled", partition="sequence", whole_sequence=True,
    inputs={"points": "suit_points", "images": "suit_images"},
    reads={"points": ("position",), "images": ("corner_face", "corner_bary", "cells")},
    description="the body fitted to the observed corners, their displacements filled by Eq. 8 and reposed (§5)",
))
register(TaskSpec(
    name="hide_corners", fn=Lazy("mocapflow.tasks.suit.holdout", "hide_corners"), version="1",
    params=HoldoutConfig, output="suit_points", partition="sequence",
    whole_sequence=True, inputs={"points": "suit_points"},
    description="hide a seeded share of observed corners for runs of frames, to score the hole filling",
))

register(TaskSpec(
    name="reflector_mask", fn=masks.masks, version="1", params=masks.MaskConfig, output="reflector_masks",
    partition="view", inputs={"frames": "raw_sequence"}, reads={"frames": ("depth", "ir")},
    description="IR threshold, morphology, connected components; colorized depth with reflectors black",
))
register(TaskSpec(
    name="dis", fn=flow.dis, version="1", params=flow.DisConfig, output="scene_flow", partition="view",
    inputs={"frames": "raw_sequence"}, reads={"frames": ("depth", "ir") + CALIBRATION}, halo=(1, 0),
    description="OpenCV DIS optical flow on IR, lifted to 3D with both depth maps",
))
register(TaskSpec(
    name="primal_dual", fn=Lazy("mocapflow.tasks.deepmocap.pdflow", "primal_dual"), version="2", params=flow.PrimalDualConfig,
    output="scene_flow",
    partition="view", inputs={"frames": "raw_sequence"}, reads={"frames": ("depth", "ir") + CALIBRATION},
    halo=(1, 0), description="primal-dual RGB-D scene flow (Jaimez et al. 2015) on IR + depth, torch",
))

# 2D reflector-set estimation (DeepMoCap §3.3): training samples, training, inference, greedy inference.
register(TaskSpec(
    name="fcn_samples", fn=training.fcn_samples, version="1",
    params=training.SampleConfig, output="fcn_samples", partition="view",
    inputs={"masks": "reflector_masks", "flow": "scene_flow", "frames": "raw_sequence"},
    reads={"masks": ("colorized_depth", "blob_id", "blob_area"), "flow": ("colorized_flow",),
           "frames": ("gt_reflectors2d", "gt_pixels")},
    halo=(1, 0), description="FCN training samples: both streams at the sample scale, subject box, 2D ground truth",
))
register(TaskSpec(
    name="train_fcn", fn=training.train_fcn, version="3",
    params=training.TrainConfig, output="fcn_weights", partition="dataset",
    inputs={"samples": "fcn_samples"}, description="train the two-stream multi-stage FCN (seeded; GPU if present)",
))
register(TaskSpec(
    name="fcn_heatmaps", fn=Lazy("mocapflow.tasks.deepmocap.heatmaps", "fcn_heatmaps"), version="3",
    params=HeatmapConfig, output="heatmaps", partition="view",
    inputs={"masks": "reflector_masks", "flow": "scene_flow"},
    reads={"masks": ("colorized_depth", "blob_id", "blob_area"), "flow": ("colorized_flow",)},
    weights_params=("weights",), packaged_weights={"weights": "deepmocap_fcn.pt"},
    description="two-stream FCN inference: confidence maps S and optical flow fields L",
))
register(TaskSpec(
    name="greedy_reflectors", fn=reflectors2d.greedy_reflectors, version="6", params=reflectors2d.GreedyConfig,
    output="reflectors2d", partition="view", inputs={"heatmaps": "heatmaps", "masks": "reflector_masks"},
    reads={"masks": ("blob_id", "blob_area")}, halo=(1, 0),
    description="NMS peaks, OFF line integral (Eq. 7-9), region filtering: labelled 2D reflectors",
))

# 3D optical data (DeepMoCap §3.4): 2D -> 3D and fusion, then temporal filtering.
register(TaskSpec(
    name="fuse_views", fn=markers3d.markers3d, version="4", params=markers3d.Markers3DConfig, output="markers3d",
    partition="sequence", inputs={"reflectors": "reflectors2d", "masks": "reflector_masks", "frames": "raw_sequence"},
    reads={"reflectors": ("x", "y", "confidence", "recovered"), "masks": ("blob_id",), "frames": ("depth",) + CALIBRATION},
    description="region-contour depth, back-projection, patch mean / strap normal-line fusion (Eq. 10, A1)",
))
for name, fn, params, version, what in (
        ("kalman", smoothing.kalman, smoothing.KalmanConfig, "9",
         "labels kept continuous (a limb under both labels loses one, exchanges undone by Viterbi, a label on "
         "another reflector's track dropped), then a filterpy Kalman filter (optionally an IMM of a slow and a "
         "fast model): confirmed track starts, gating, competing tracks chosen by support and top speed, gaps "
         "bridged, optional RTS smoothing"),
        ("butterworth", smoothing.butterworth, smoothing.ButterworthConfig, "1", "zero-phase Butterworth low-pass"),
        ("none", smoothing.no_smoothing, smoothing.NoSmoothing, "1", "the fused markers unchanged")):
    register(TaskSpec(name=name, fn=fn, version=version, params=params, output="smoothed_markers", partition="sequence",
                      inputs={"markers": "markers3d"}, whole_sequence=True, description=what))

# Motion capture (DeepMoCap §3.5): template calibration per sequence, then the poses.
register(TaskSpec(
    name="calibrate_skeleton", fn=skeleton.calibrate_skeleton, version="5", params=skeleton.SkeletonConfig,
    output="skeleton", partition="sequence", inputs={"markers": "smoothed_markers"}, whole_sequence=True,
    description="coarse scaling, segment-scale fit, per-level particle joint estimation (Eq. 11, robust), "
                "reflector offsets per bone",
))
register(TaskSpec(
    name="solve_poses", fn=poses.solve_poses, version="5", params=poses.PoseConfig, output="poses",
    partition="sequence", inputs={"skeleton": "skeleton", "markers": "smoothed_markers", "views": "markers3d"},
    reads={"views": ("view_position", "view_confidence")}, whole_sequence=True,
    description="40-DoF least squares per frame against the calibrated reflector offsets, warm-started from an "
                "anchor frame; wrong labels gated out, lost limbs taken back, outvoted single views used",
))

# Beyond the paper: no gross error written as data (tasks/deepmocap/plausibility.py).
register(TaskSpec(
    name="check_plausibility", fn=plausibility.check_markers, version="1", params=plausibility.PlausibilityConfig,
    output="smoothed_markers", partition="sequence",
    inputs={"markers": "smoothed_markers", "poses": "poses", "skeleton": "skeleton", "frames": "raw_sequence"},
    reads={"poses": ("position", "rotation"), "skeleton": ("parent", "bone", "reflector_offset"), "frames": CALIBRATION},
    whole_sequence=True,
    description="markers outside the sensors' common capture volume or off their reflector on the solved pose removed",
))

# Beyond the paper: each view's 2D reflectors made consistent with the solved poses (tasks/deepmocap/refine2d.py).
register(TaskSpec(
    name="refine_reflectors", fn=refine2d.refine_reflectors, version="1", params=refine2d.Refine2DConfig,
    output="reflectors2d", partition="view",
    inputs={"reflectors": "reflectors2d", "poses": "poses", "skeleton": "skeleton", "masks": "reflector_masks",
            "frames": "raw_sequence"},
    reads={"poses": ("position", "rotation"), "skeleton": ("parent", "bone", "reflector_offset"),
           "masks": ("blob_id", "blob_area"), "frames": ("depth",) + CALIBRATION},
    description="mirrored labels exchanged and missing reflectors added where the solved poses project",
))

# UUO (Milef et al. 2024): unlabelled markers anywhere on the body.
register(TaskSpec(
    name="rigid_segments", fn=segmentation.rigid_segments, version="2", params=segmentation.SegmentConfig,
    output="marker_segments", partition="sequence", inputs={"markers": "raw_markers"}, reads={"markers": ("position",)},
    whole_sequence=True,
    description="group unlabelled markers by the bone they ride: spread of pairwise distances, agglomerative clustering",
))
register(TaskSpec(
    name="simulated_prior", fn=prior.simulated_prior, version="2", params=prior.SimulatedPriorConfig,
    output="body_prior", partition="sequence", inputs={"markers": "raw_markers"}, whole_sequence=True,
    description="the studio's true body degraded like a monocular estimate (rotation errors, yaw, size, position, "
                "lost frames)",
))
register(TaskSpec(
    name="no_prior", fn=prior.no_prior, version="1", params=prior.NoPriorConfig,
    output="body_prior", partition="sequence", inputs={"markers": "raw_markers"}, reads={"markers": ("position",)},
    whole_sequence=True,
    description="markers only: a neutral body standing in its rest pose as the prior (the paper's marker-only rows)",
))
register(TaskSpec(
    name="solve_hypothesis", fn=solve.solve_hypothesis, version="1", params=solve.HypothesisConfig,
    output="uuo_body", partition="sequence", whole_sequence=True,
    inputs={"markers": "raw_markers", "segments": "marker_segments", "prior": "body_prior"},
    reads={"markers": ("position",)},
    description="UUO from one root-yaw hypothesis: part matching, chamfer pose fit, marker-vertex correspondence, "
                "inverse kinematics (§3.4-3.5, stages 2-4)",
))
register(TaskSpec(
    name="best_hypothesis", fn=solve.best_hypothesis, version="1", params=solve.RefineConfig,
    output="uuo_body", partition="sequence", whole_sequence=True,
    inputs={"markers": "raw_markers", "yaw0": "uuo_body", "yaw90": "uuo_body", "yaw180": "uuo_body",
            "yaw270": "uuo_body"},
    reads={"markers": ("position",)},
    description="the root-yaw hypothesis of least chamfer (Eq. 3), refined (stage 5)",
))
register(TaskSpec(
    name="single_hypothesis", fn=solve.single_hypothesis, version="1", params=solve.RefineConfig,
    output="uuo_body", partition="sequence", whole_sequence=True, inputs={"markers": "raw_markers", "yaw0": "uuo_body"},
    reads={"markers": ("position",)},
    description="one root-yaw hypothesis, refined (the paper's '- MHT' ablation, Table 3)",
))
register(TaskSpec(
    name="rigid_prior", fn=solve.rigid_prior, version="1", params=solve.RigidPriorConfig,
    output="uuo_body", partition="sequence", whole_sequence=True,
    inputs={"markers": "raw_markers", "segments": "marker_segments", "prior": "body_prior"},
    reads={"markers": ("position",)},
    description="baseline: the prior placed on the markers by part matching from each root yaw, the placement "
                "of least chamfer kept, no pose solved (the paper's HMR2.0+RR)",
))
register(TaskSpec(
    name="file_prior", fn=prior.file_prior, version="2", params=prior.FilePriorConfig,
    output="body_prior", partition="sequence", inputs={"markers": "raw_markers"},
    reads={"markers": ("position", "prior_joints")}, whole_sequence=True,
    description="a monocular estimate brought as template joints per frame (the take's prior file), Anny fitted "
                "to them",
))
register(TaskSpec(
    name="reference_prior", fn=prior.reference_prior, version="1", params=prior.SimulatedPriorConfig,
    output="body_prior", partition="sequence", inputs={"markers": "raw_markers", "reference": "uuo_body"},
    reads={"markers": ("position",), "reference": ("bone_rotation", "root", "joints")}, whole_sequence=True,
    description="a solved reference body (a recorded take's labelled solve) degraded like a monocular estimate",
))
register(TaskSpec(
    name="merge_labels", fn=labelled.merge_labels, version="1", params=labelled.MergeLabelsConfig,
    output="raw_markers", partition="sequence", inputs={"markers": "raw_markers"},
    reads={"markers": ("position", "timestamp", "label")}, whole_sequence=True,
    description="a labelled recording's fragments of one label joined, unlabelled trajectories dropped (the "
                "labelled reference's markers)",
))
register(TaskSpec(
    name="drop_labels", fn=labelled.drop_labels, version="1", params=labelled.DropLabelsConfig,
    output="raw_markers", partition="sequence", inputs={"markers": "raw_markers"},
    reads={"markers": ("position", "timestamp")}, whole_sequence=True,
    description="a recording's labels hidden: trajectories m000, m001, ... in the file's order",
))

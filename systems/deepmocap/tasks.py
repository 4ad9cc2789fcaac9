"""The DeepMoCap system's task specs (Chatzitofis et al., Sensors 2019): how the engine drives each stage of
tasks/deepmocap (see registry.TaskSpec)."""

from __future__ import annotations

from mocapflow.pipeline.registry import Lazy, NoParams, TaskSpec
from mocapflow.tasks.deepmocap import (body_poses, flow, markers3d, masks, plausibility, poses, refine2d, reflectors2d,
                                       skeleton, smoothing, training)
from mocapflow.tasks.deepmocap.heatmaps import HeatmapConfig
from mocapflow.tasks.shared.cameras import CALIBRATION_VARIABLES as CALIBRATION

_SMOOTHERS = (
        ("kalman", smoothing.kalman, smoothing.KalmanConfig, "9",
         "labels kept continuous (a limb under both labels loses one, exchanges undone by Viterbi, a label on "
         "another reflector's track dropped), then a filterpy Kalman filter (optionally an IMM of a slow and a "
         "fast model): confirmed track starts, gating, competing tracks chosen by support and top speed, gaps "
         "bridged, optional RTS smoothing"),
        ("butterworth", smoothing.butterworth, smoothing.ButterworthConfig, "1", "zero-phase Butterworth low-pass"),
        ("none", smoothing.no_smoothing, smoothing.NoSmoothing, "1", "the fused markers unchanged"))


TASKS = (
    # The `frames` stage: every raw sequence of a dataset synthesized (studio) or imported
    # (zarr, image folders) into the raw-sequence schema. The dataset reader runs it.
    TaskSpec(
        name="ingest",
        fn=None,
        version="1",
        params=NoParams,
        output="raw_sequence",
        partition="sequence",
        source=True,
        description="synthesize or import a dataset's sequences into the raw-sequence schema",
    ),

    TaskSpec(
        name="reflector_mask", fn=masks.masks, version="1", params=masks.MaskConfig, output="reflector_masks",
        partition="view", inputs={"frames": "raw_sequence"}, reads={"frames": ("depth", "ir")},
        description="IR threshold, morphology, connected components; colorized depth with reflectors black",
    ),
    TaskSpec(
        name="dis", fn=flow.dis, version="1", params=flow.DisConfig, output="scene_flow", partition="view",
        inputs={"frames": "raw_sequence"}, reads={"frames": ("depth", "ir") + CALIBRATION}, halo=(1, 0),
        description="OpenCV DIS optical flow on IR, lifted to 3D with both depth maps",
    ),
    TaskSpec(
        name="primal_dual", fn=Lazy("mocapflow.tasks.deepmocap.pdflow", "primal_dual"), version="2",
        params=flow.PrimalDualConfig, output="scene_flow",
        partition="view", inputs={"frames": "raw_sequence"}, reads={"frames": ("depth", "ir") + CALIBRATION},
        halo=(1, 0), description="primal-dual RGB-D scene flow (Jaimez et al. 2015) on IR + depth, torch",
    ),

    # 2D reflector-set estimation (DeepMoCap §3.3): training samples, training, inference, greedy inference.
    TaskSpec(
        name="fcn_samples", fn=training.fcn_samples, version="1",
        params=training.SampleConfig, output="fcn_samples", partition="view",
        inputs={"masks": "reflector_masks", "flow": "scene_flow", "frames": "raw_sequence"},
        reads={"masks": ("colorized_depth", "blob_id", "blob_area"), "flow": ("colorized_flow",),
               "frames": ("gt_reflectors2d", "gt_pixels")},
        halo=(1, 0), description="FCN training samples: both streams at the sample scale, subject box, 2D ground truth",
    ),
    TaskSpec(
        name="train_fcn", fn=training.train_fcn, version="3",
        params=training.TrainConfig, output="fcn_weights", partition="dataset",
        inputs={"samples": "fcn_samples"}, streams={"samples": training.IMAGES}, checkpoints=True,
        weights_params=("init", "teacher"),
        description="train the two-stream multi-stage FCN (seeded; GPU if present; images streamed from storage, "
                    "resumable from its checkpoint)",
    ),
    TaskSpec(
        name="fcn_heatmaps", fn=Lazy("mocapflow.tasks.deepmocap.heatmaps", "fcn_heatmaps"), version="3",
        params=HeatmapConfig, output="heatmaps", partition="view",
        inputs={"masks": "reflector_masks", "flow": "scene_flow"},
        reads={"masks": ("colorized_depth", "blob_id", "blob_area"), "flow": ("colorized_flow",)},
        weights_params=("weights",), packaged_weights={"weights": "deepmocap_fcn.pt"},
        description="two-stream FCN inference: confidence maps S and optical flow fields L",
    ),
    TaskSpec(
        name="greedy_reflectors", fn=reflectors2d.greedy_reflectors, version="6", params=reflectors2d.GreedyConfig,
        output="reflectors2d", partition="view", inputs={"heatmaps": "heatmaps", "masks": "reflector_masks"},
        reads={"masks": ("blob_id", "blob_area")}, halo=(1, 0),
        description="NMS peaks, OFF line integral (Eq. 7-9), region filtering: labelled 2D reflectors",
    ),

    # 3D optical data (DeepMoCap §3.4): 2D -> 3D and fusion, then temporal filtering.
    TaskSpec(
        name="fuse_views", fn=markers3d.markers3d, version="4", params=markers3d.Markers3DConfig, output="markers3d",
        partition="sequence", inputs={"reflectors": "reflectors2d", "masks": "reflector_masks", "frames": "raw_sequence"},
        reads={"reflectors": ("x", "y", "confidence", "recovered"), "masks": ("blob_id",), "frames": ("depth",) + CALIBRATION},
        description="region-contour depth, back-projection, patch mean / strap normal-line fusion (Eq. 10, A1)",
    ),
        *(TaskSpec(name=name, fn=fn, version=version, params=params, output="smoothed_markers", partition="sequence",
               inputs={"markers": "markers3d"}, whole_sequence=True, description=what)
      for name, fn, params, version, what in _SMOOTHERS),
    # Motion capture (DeepMoCap §3.5): template calibration per sequence, then the poses.
    TaskSpec(
        name="calibrate_skeleton", fn=skeleton.calibrate_skeleton, version="5", params=skeleton.SkeletonConfig,
        output="skeleton", partition="sequence", inputs={"markers": "smoothed_markers"}, whole_sequence=True,
        description="coarse scaling, segment-scale fit, per-level particle joint estimation (Eq. 11, robust), "
                    "reflector offsets per bone",
    ),
    TaskSpec(
        name="solve_poses", fn=poses.solve_poses, version="5", params=poses.PoseConfig, output="poses",
        partition="sequence", inputs={"skeleton": "skeleton", "markers": "smoothed_markers", "views": "markers3d"},
        reads={"views": ("view_position", "view_confidence")}, whole_sequence=True,
        description="40-DoF least squares per frame against the calibrated reflector offsets, warm-started from an "
                    "anchor frame; wrong labels gated out, lost limbs taken back, outvoted single views used",
    ),

    # Beyond the paper: poses as bodies, Anny fitted to the reflectors (tasks/deepmocap/body_poses.py).
    TaskSpec(
        name="fit_body_poses", fn=body_poses.fit_body_poses, version="1", params=body_poses.BodyPoseConfig,
        output="body_poses", partition="sequence", inputs={"markers": "smoothed_markers"},
        reads={"markers": ("position", "confidence")}, whole_sequence=True,
        description="Anny fitted to the labelled 3D reflectors (shared Levenberg-Marquardt body fit), the shape and "
                    "the reflectors' places calibrated per take; joints read from the fitted body",
    ),

    # Beyond the paper: no gross error written as data (tasks/deepmocap/plausibility.py).
    TaskSpec(
        name="check_plausibility", fn=plausibility.check_markers, version="1", params=plausibility.PlausibilityConfig,
        output="smoothed_markers", partition="sequence",
        inputs={"markers": "smoothed_markers", "poses": "poses", "skeleton": "skeleton", "frames": "raw_sequence"},
        reads={"poses": ("position", "rotation"), "skeleton": ("parent", "bone", "reflector_offset"), "frames": CALIBRATION},
        whole_sequence=True,
        description="markers outside the sensors' common capture volume or off their reflector on the solved pose removed",
    ),

    # Beyond the paper: each view's 2D reflectors made consistent with the solved poses (tasks/deepmocap/refine2d.py).
    TaskSpec(
        name="refine_reflectors", fn=refine2d.refine_reflectors, version="1", params=refine2d.Refine2DConfig,
        output="reflectors2d", partition="view",
        inputs={"reflectors": "reflectors2d", "poses": "poses", "skeleton": "skeleton", "masks": "reflector_masks",
                "frames": "raw_sequence"},
        reads={"poses": ("position", "rotation"), "skeleton": ("parent", "bone", "reflector_offset"),
               "masks": ("blob_id", "blob_area"), "frames": ("depth",) + CALIBRATION},
        description="mirrored labels exchanged and missing reflectors added where the solved poses project",
    ),
    )

"""The UUO system's task specs (Milef et al., SIGGRAPH 2024): unlabelled markers anywhere on the body, tasks/uuo."""

from __future__ import annotations

from mocapflow.pipeline.registry import NoParams, TaskSpec
from mocapflow.tasks.uuo import combine, hypotheses, labelled, monocular, prior, segmentation, solve

TASKS = (
    # The marker-file counterpart: a `markers` dataset's C3D or TRC recordings as raw_markers (frame, marker, xyz).
    TaskSpec(
        name="ingest_markers",
        fn=None,
        version="1",
        params=NoParams,
        output="raw_markers",
        partition="sequence",
        source=True,
        description="import a dataset's marker recordings (C3D, TRC) as trajectories in metres, Z up",
    ),

    # UUO (Milef et al. 2024): unlabelled markers anywhere on the body.
    TaskSpec(
        name="rigid_segments", fn=segmentation.rigid_segments, version="2", params=segmentation.SegmentConfig,
        output="marker_segments", partition="sequence", inputs={"markers": "raw_markers"}, reads={"markers": ("position",)},
        whole_sequence=True,
        description="group unlabelled markers by the bone they ride: spread of pairwise distances, agglomerative clustering",
    ),
    TaskSpec(
        name="simulated_prior", fn=prior.simulated_prior, version="4", params=prior.SimulatedPriorConfig,
        output="body_prior", partition="sequence", inputs={"markers": "raw_markers"}, whole_sequence=True,
        description="the studio's true body degraded like a monocular estimate (rotation errors, yaw, size, position, "
                    "lost frames)",
    ),
    TaskSpec(
        name="no_prior", fn=prior.no_prior, version="1", params=prior.NoPriorConfig,
        output="body_prior", partition="sequence", inputs={"markers": "raw_markers"}, reads={"markers": ("position",)},
        whole_sequence=True,
        description="markers only: a neutral body standing in its rest pose as the prior (the paper's marker-only rows)",
    ),
    TaskSpec(
        name="solve_hypothesis", fn=solve.solve_hypothesis, version="4", params=solve.HypothesisConfig,
        output="uuo_body", partition="sequence", whole_sequence=True,
        inputs={"markers": "raw_markers", "segments": "marker_segments", "prior": "body_prior"},
        reads={"markers": ("position",)},
        description="UUO from one root-yaw hypothesis: part matching, chamfer pose fit, marker-vertex correspondence, "
                    "inverse kinematics (§3.4-3.5, stages 2-4)",
    ),
    TaskSpec(
        name="screen_hypotheses", fn=solve.screen_hypotheses, version="1", params=hypotheses.ScreenConfig,
        output="uuo_screen", partition="sequence", whole_sequence=True,
        inputs={"markers": "raw_markers", "segments": "marker_segments", "prior": "body_prior"},
        reads={"markers": ("position",)},
        description="the prior placed by part matching from every root yaw 30 degrees apart and mirrored, the "
                    "placements facing apart ranked by chamfer for the solve stages (§3.5.1, widened)",
    ),
    TaskSpec(
        name="solve_screened", fn=solve.solve_screened, version="1", params=solve.ScreenedConfig,
        output="uuo_body", partition="sequence", whole_sequence=True,
        inputs={"markers": "raw_markers", "segments": "marker_segments", "prior": "body_prior",
                "screen": "uuo_screen"},
        reads={"markers": ("position",)},
        description="UUO from the screen's placement of a given rank: chamfer pose fit, marker-vertex "
                    "correspondence, inverse kinematics (§3.5, stages 2-4)",
    ),
    TaskSpec(
        name="best_hypothesis", fn=solve.best_hypothesis, version="5", params=solve.RefineConfig,
        output="uuo_body", partition="sequence", whole_sequence=True,
        inputs={"markers": "raw_markers", "h0": "uuo_body", "h1": "uuo_body", "h2": "uuo_body", "h3": "uuo_body"},
        reads={"markers": ("position",)},
        description="of four solved hypotheses, the one of least chamfer (Eq. 3; among close ones, the most "
                    "plausible: pose agreeing with the prior, rigid groups on one side, hinges bent their way), "
                    "refined (stage 5); a runner-up facing otherwise within call_deg is reported too close to call",
    ),
    TaskSpec(
        name="single_hypothesis", fn=solve.single_hypothesis, version="5", params=solve.RefineConfig,
        output="uuo_body", partition="sequence", whole_sequence=True, inputs={"markers": "raw_markers", "h0": "uuo_body"},
        reads={"markers": ("position",)},
        description="one root-yaw hypothesis, refined (the paper's '- MHT' ablation, Table 3)",
    ),
    TaskSpec(
        name="rigid_prior", fn=solve.rigid_prior, version="1", params=solve.RigidPriorConfig,
        output="uuo_body", partition="sequence", whole_sequence=True,
        inputs={"markers": "raw_markers", "segments": "marker_segments", "prior": "body_prior"},
        reads={"markers": ("position",)},
        description="baseline: the prior placed on the markers by part matching from each root yaw, the placement "
                    "of least chamfer kept, no pose solved (the paper's HMR2.0+RR)",
    ),
    TaskSpec(
        name="file_prior", fn=prior.file_prior, version="2", params=prior.FilePriorConfig,
        output="body_prior", partition="sequence", inputs={"markers": "raw_markers"},
        reads={"markers": ("position", "prior_joints")}, whole_sequence=True,
        description="a monocular estimate brought as template joints per frame (the take's prior file), Anny fitted "
                    "to them",
    ),
    TaskSpec(
        name="monocular_prior", fn=monocular.monocular_prior, version="1", params=monocular.MonocularPriorConfig,
        output="body_prior", partition="sequence", inputs={"markers": "raw_markers"},
        reads={"markers": ("position", "video")}, whole_sequence=True, weights_params=("detector", "landmarker"),
        description="a real monocular estimate: BlazePose GHUM 3D on the take's video (its .tflite networks under "
                    "LiteRT), Anny fitted to its joints",
    ),
    TaskSpec(
        name="reference_prior", fn=prior.reference_prior, version="3", params=prior.SimulatedPriorConfig,
        output="body_prior", partition="sequence", inputs={"markers": "raw_markers", "reference": "uuo_body"},
        reads={"markers": ("position",), "reference": ("bone_rotation", "root", "joints")}, whole_sequence=True,
        description="a solved reference body (a recorded take's labelled solve) degraded like a monocular estimate",
    ),
    TaskSpec(
        name="combine_priors", fn=combine.combine_priors, version="1", params=combine.CombinePriorsConfig,
        output="body_prior", partition="sequence", whole_sequence=True,
        inputs={"prior0": "body_prior", "prior1": "body_prior", "prior2": "body_prior"},
        reads={"prior0": ("bone_rotation", "root", "joints", "valid"),
               "prior1": ("bone_rotation", "root", "joints", "valid"),
               "prior2": ("bone_rotation", "root", "joints", "valid")},
        description="three prior draws or estimates of one take combined robustly: aligned by one yaw, each joint's "
                    "rotation a Cauchy-weighted mean from the median, the roots' median, a frame valid in two",
    ),
    TaskSpec(
        name="merge_labels", fn=labelled.merge_labels, version="1", params=labelled.MergeLabelsConfig,
        output="raw_markers", partition="sequence", inputs={"markers": "raw_markers"},
        reads={"markers": ("position", "timestamp", "label")}, whole_sequence=True,
        description="a labelled recording's fragments of one label joined, unlabelled trajectories dropped (the "
                    "labelled reference's markers)",
    ),
    TaskSpec(
        name="drop_labels", fn=labelled.drop_labels, version="1", params=labelled.DropLabelsConfig,
        output="raw_markers", partition="sequence", inputs={"markers": "raw_markers"},
        reads={"markers": ("position", "timestamp")}, whole_sequence=True,
        description="a recording's labels hidden: trajectories m000, m001, ... in the file's order",
    ),
    )

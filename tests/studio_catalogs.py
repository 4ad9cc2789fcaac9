"""Small studio catalogs that run fast, shared by the tests of one system's engine run and of its report."""

# UUO's first stages with an exact prior and fast solver settings (`*fast`), shared by the catalogs below
UUO_FAST_STAGES = """\
  markers: {task: ingest_markers, dataset: uuo}
  segments: {task: rigid_segments, inputs: [markers]}
  prior:
    task: simulated_prior
    inputs: [markers]
    params: {form: mild, rotation_deg: 0.0, yaw_deg: 0.0, lost: 0.0, phenotype_noise: 0.0, drift_m: 0.0}
  screen: {task: screen_hypotheses, inputs: [markers, segments, prior], params: {matching: {frames: 12, iterations: 12}}}
  h0:
    task: solve_screened
    inputs: [markers, segments, prior, screen]
    params:
      rank: 0
      solve: &fast
        matching: {frames: 12, iterations: 12}
        pose_fit: {rounds: 3, iterations: 10}
        ik: {iterations: 40}
"""


UUO_CATALOG = """\
data_roots: [.]
storage: {root: storage/, region_frames: 8}
datasets:
  uuo:
    kind: studio_markers
    defaults: {frames: 24, views: 1}
    markers: {count: 30, occlusion: false, break_per_s: 0.0, ghosts_per_s: 1.25}   # all visible, one ghost in 0.8 s
    sequences:
      reach: {motion: side_reaches, seed: 8}
stages:
""" + UUO_FAST_STAGES + """\
  h1: {task: solve_screened, inputs: [markers, segments, prior, screen], params: {rank: 1, solve: *fast}}
  h2: {task: solve_screened, inputs: [markers, segments, prior, screen], params: {rank: 2, solve: *fast}}
  h3: {task: solve_screened, inputs: [markers, segments, prior, screen], params: {rank: 3, solve: *fast}}
  solve:
    task: best_hypothesis
    inputs: {markers: markers, h0: h0, h1: h1, h2: h2, h3: h3}
    params: {ik: {iterations: 40}}
"""

SUIT_CATALOG = """\
data_roots: [.]
storage: {root: storage/, region_frames: 4}
datasets:
  suits:
    kind: studio_suit
    suit: small
    cameras: {count: 4, width: 384, height: 512}
    defaults: {frames: 3}
    sequences:
      sq: {motion: classic_squat, seed: 11}
stages:
  images: {task: ingest_suit, dataset: suits}
  labels: {task: oracle_labels, inputs: [images], params: {noise_px: 0.2, wrong: 0.02}}
  points: {task: triangulate_corners, inputs: {labels: labels, images: images}}
  perturbed: {task: triangulate_corners, inputs: {labels: labels, images: images}, params: {calibration_error_px: 0.25}}
  hidden: {task: hide_corners, inputs: [points], params: {share: 0.2, run_frames: [1, 2], shape: patch}}
  filled: {task: fill_suit, inputs: {points: hidden, images: images}}
"""

# One performance filmed by the three systems (pipeline/catalog.py JointTake): DeepMoCap and UUO at 30 fps, the
# suit at 10 fps (every third instant shared); the suit's 3D half on truth labels, to keep the test short.
JOINT_CATALOG = """\
data_roots: [.]
storage: {root: storage/, region_frames: 32}
joint_take:
  datasets: [dmc, uuo, suit]
  defaults: {fps: 30.0, frames: 30, start_s: 0.2}
  sequences:
    squat: {motion: classic_squat, seed: 21}
datasets:
  dmc:
    kind: studio
    defaults: {views: 3, noise: 1.0, body: mesh}
  uuo:
    kind: studio_markers
    defaults: {views: 1}
    markers: {count: 30, occlusion: false, break_per_s: 0.0, ghosts_per_s: 1.0}   # all visible, one ghost in 1 s
  suit:
    kind: studio_suit
    suit: small
    cameras: {count: 4, width: 384, height: 512}
    defaults: {fps: 10.0, frames: 10}
stages:
  frames: {task: ingest, dataset: dmc}
  masks: {task: reflector_mask, inputs: [frames]}
  flow: {task: dis, inputs: [frames]}
  heatmaps: {task: fcn_heatmaps, inputs: {masks: masks, flow: flow}}
  reflectors2d: {task: greedy_reflectors, inputs: {heatmaps: heatmaps, masks: masks}}
  markers3d: {task: fuse_views, inputs: {reflectors: reflectors2d, masks: masks, frames: frames}}
  smoothed: {task: kalman, inputs: {markers: markers3d}}
  skeleton: {task: calibrate_skeleton, inputs: {markers: smoothed}}
  poses: {task: solve_poses, inputs: {skeleton: skeleton, markers: smoothed, views: markers3d}}
""" + UUO_FAST_STAGES + """\
  h1: {task: solve_screened, inputs: [markers, segments, prior, screen], params: {rank: 1, solve: *fast}}
  solve:
    task: best_hypothesis
    inputs: {markers: markers, h0: h0, h1: h0, h2: h1, h3: h1}
    params: {ik: {iterations: 40}}
  images: {task: ingest_suit, dataset: suit}
  labels: {task: oracle_labels, inputs: [images], params: {noise_px: 0.2, wrong: 0.02}}
  points: {task: triangulate_corners, inputs: {labels: labels, images: images}}
  filled: {task: fill_suit, inputs: {points: points, images: images}}
"""

"""Kernels of the markerless system (systems/markerless): BlazePose's 2D keypoints in every calibrated view
(blazepose.py), triangulated with Pose2Sim's outlier rule (triangulate.py), read as the template's 20 joints
(joints.py). See docs/markerless.md."""

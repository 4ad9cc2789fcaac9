"""The synthetic capture studio, a shared floor of the systems: a posed body filmed with generic cameras and lights.

DeepMoCap's datasets (DMC2.5D, DMC3D; Chatzitofis et al., Sensors 2019, §4) are available only on request, nor are
UUO's or the suit's recordings ours, so the studio makes takes with ground truth for every stage:

- ``spec``        what a sequence films (SequenceSpec) and the versions its fingerprint names
- ``motion``      DMC3D's 15 exercises, procedurally
- ``retarget``    real (CMU) motion, a BVH clip or ASF/AMC take parsed by formats/, retargeted onto the template
- ``take``        a subject performing the motion on the mesh body (``mesh_motion``: the skinning)
- ``cameras``     intrinsics, distortion and layouts; ``mesh_render``: ray casting the mesh, its lights and shading

Each system films a take with these from its own kernels: DeepMoCap's IR-depth sensors and reflectors
(tasks/deepmocap/film), UUO's markers and video (tasks/uuo/takes.py, video.py), the suit's cameras
(tasks/suit/takes.py). The body (the 20-joint template and its surface), the reflector table, the Camera type and
the kinematics are the shared kernels' (``mocapflow.tasks.shared``); the studio imports no system's kernels.
"""

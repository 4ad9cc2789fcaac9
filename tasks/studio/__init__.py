"""The synthetic capture studio: an articulated reflector-wearing body filmed by Kinect-v2-like IR-D sensors.

DeepMoCap's datasets (DMC2.5D, DMC3D; Chatzitofis et al., Sensors 2019, §4) are available only on
request, so the studio renders faithful stand-ins with ground truth for every stage:

- ``motion``      DMC3D's 15 exercises, procedurally
- ``bvh``         BVH import and retargeting of real (CMU) motion onto the template
- ``cameras``     Kinect-v2-like intrinsics, distortion and layouts
- ``render``      ray-cast depth and IR with Kinect-like artifacts, reflector ids and scene flow
- ``synth``       one sequence's frame region as a raw-sequence Dataset

The body (the 20-joint template and its surface), the reflector table, the Camera type and the kinematics
are the shared floor's (``mocapflow.tasks.shared``): the studio uses them, the stages never import the studio.
"""

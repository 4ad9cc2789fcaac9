"""The shared floor every capture system and the studio stand on: cameras, triangulation, rotations and kinematics,
the body, labels, and small utilities."""

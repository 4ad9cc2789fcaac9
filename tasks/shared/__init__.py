"""The shared floor every capture system and the studio stand on: cameras, rotations and kinematics, the body,
its reflector table, labels, and small utilities. No module here imports a system or the studio."""

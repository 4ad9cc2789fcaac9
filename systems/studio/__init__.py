"""The studio, the source of takes: a subject performing a motion on the mesh (or capsule) body, with its ground
truth (tasks/studio).

A shared floor, not a system: it registers nothing. Its sequence specs, motion files, fingerprints and takes
(specs.py, tasks/studio/spec.py and take.py) and its generic cameras, lights and renderers (tasks/studio) are
used by every system that films a take, and each films it from its own package and registers that dataset kind:
DeepMoCap ``studio`` (systems/deepmocap/film.py, its IR-depth sensors; ``mocapflow synth``, its cli.py), UUO
``studio_markers`` (systems/uuo/film.py) and the suit ``studio_suit`` (systems/suit/film.py). It imports no
system's package or kernels.
"""

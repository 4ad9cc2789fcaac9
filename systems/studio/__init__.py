"""The studio, the source of takes: a subject performing a motion on the mesh (or capsule) body, with its ground
truth, filmed the way each system films (tasks/studio).

It adds three dataset kinds, one filming module each, all on the take core (specs.py, tasks/studio/take.py):
``studio`` (film_deepmocap.py: the IR-depth sensors, raw sequences), ``studio_markers`` (film_uuo.py: a UUO marker
layout, raw markers) and ``studio_suit`` (film_suit.py: the suit's grey cameras, suit images). It imports no
system's stages: the datasets it writes are in the schemas the systems share.
"""

from mocapflow.pipeline.registry import System
from mocapflow.systems.studio.film_deepmocap import StudioReader
from mocapflow.systems.studio.film_suit import StudioSuitReader
from mocapflow.systems.studio.film_uuo import StudioMarkersReader

SYSTEM = System(
    name="studio",
    description="the synthetic studio: real or procedural motion on a mesh body, filmed as each system films",
    dataset_kinds={"studio": StudioReader, "studio_markers": StudioMarkersReader, "studio_suit": StudioSuitReader},
)

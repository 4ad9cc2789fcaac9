"""The studio filmed as UUO sees it: the dataset kind ``studio_markers``, unlabelled marker takes on the mesh body.

    datasets:
      uuo:
        kind: studio_markers
        defaults: {frames: 100, fps: 30.0, start_s: 0.5}
        markers: {count: 40, part: body, dropout: 0.002, ghosts: 3}   # occlusion: true loses what the cameras miss
        sequences:
          walk_body40: {motion: ../shared/data/motions/cmu_12_01_walk.bvh, seed: 9101}
          knee_left_leg: {motion: jumping_jack, seed: 9104, markers: {count: 20, part: left_leg}}

A sequence's (and the dataset's) ``markers`` say how many markers, on which part, and what goes wrong while
recording (tasks/studio/uuo_takes.py); the take is the studio's (tasks/studio/take.py), nothing else is filmed.
"""

from __future__ import annotations

import dataclasses
import typing
from typing import Any, Mapping

import numpy as np

from mocapflow.pipeline.datasets import SequenceInfo
from mocapflow.pipeline.errors import CatalogError
from mocapflow.pipeline.hashing import digest
from mocapflow.pipeline.registry import coerce, did_you_mean
from mocapflow.systems.studio.specs import fingerprint, frame_count, sequence_specs, take_for
from mocapflow.tasks.shared.cache import BoundedCache
from mocapflow.tasks.shared.mesh_body import PARTS
from mocapflow.tasks.studio import uuo_takes as uuo

MARKER_DEFAULTS = {"count": 40, "part": "body"}
_CAPTURES: BoundedCache[str, tuple] = BoundedCache(4)  # fingerprint -> (layout, captured), this process


def marker_options(raw: Mapping[str, Any] | None, where: str) -> tuple[int, str, uuo.MarkerFaults]:
    """(marker count, body part, capture faults) from a ``markers`` mapping, checked."""
    raw = {**MARKER_DEFAULTS, **(raw or {})}
    fields = {f.name: f for f in dataclasses.fields(uuo.MarkerFaults)}
    for key in raw:
        if key not in fields and key not in MARKER_DEFAULTS:
            known = sorted(set(fields) | set(MARKER_DEFAULTS))
            raise CatalogError(f"{where}: unknown markers field {key!r}{did_you_mean(key, known)}; fields: {known}")
    count = coerce(raw["count"], int, f"{where}.count")
    if count < 1 or raw["part"] not in PARTS:
        raise CatalogError(f"{where}: markers need count >= 1 (got {count}) and a part among {sorted(PARTS)} "
                           f"(got {raw['part']!r})")
    hints = typing.get_type_hints(uuo.MarkerFaults)
    values = {k: coerce(tuple(v) if isinstance(v, list) else v, hints[k], f"{where}.{k}")
              for k, v in raw.items() if k in fields}
    try:
        return count, str(raw["part"]), uuo.MarkerFaults(**values)
    except (ValueError, TypeError) as exc:
        raise CatalogError(f"{where}: {exc}") from exc


class StudioMarkersReader:
    """Unlabelled marker takes filmed on the studio's mesh body (UUO), as raw_markers with ground truth."""

    options = ("sequences", "defaults", "markers")
    has_views = False

    @staticmethod
    def discover(catalog, dataset) -> list[SequenceInfo]:
        out = []
        for seq_id, where, extra, (spec, text, source) in sequence_specs(catalog, dataset, "studio_markers",
                                                                         mesh_only=True):
            markers = marker_options({**(dataset.options.get("markers") or {}), **(extra.get("markers") or {})},
                                     where)
            fp = digest({"take": fingerprint(spec, text),
                         "markers": [markers[0], markers[1], dataclasses.asdict(markers[2])]})
            out.append(SequenceInfo(seq_id, (), frame_count(spec, text), fp,
                                    {"spec": spec, "source": source, "markers": markers}))
        return out

    @staticmethod
    def read(dataset, seq: SequenceInfo, start: int, stop: int):
        shot = take_for(seq)
        count, part, faults = seq.spec["markers"]

        def record():
            layout = uuo.layout(shot.body, np.random.default_rng([shot.spec.seed, 3]), count, part)
            vertices = shot.mesh.posed.vertices[:shot.n_frames]
            paths = uuo.marker_paths(shot.body, layout, vertices)
            seen_by = uuo.cameras_seeing(vertices, shot.body.faces, paths, uuo.optical_cameras()) \
                if faults.occlusion else None
            return layout, uuo.capture(paths, faults, np.random.default_rng([shot.spec.seed, 4]), seen_by)

        layout, captured = _CAPTURES.get_or_make(seq.fingerprint, record)
        return uuo.marker_dataset(shot.body, layout, captured, shot.mesh, shot.spec.fps, start, stop)

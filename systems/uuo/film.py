"""The studio filmed as UUO sees it: the dataset kind ``studio_markers``, unlabelled marker takes on the mesh body.

    datasets:
      uuo:
        kind: studio_markers
        defaults: {frames: 100, fps: 30.0, start_s: 0.5}
        markers: {count: 40, part: body}   # as an optical system records; occlusion: false for all-visible takes
        video: {width: 640, height: 480}   # optional: a colour video of the take too (a monocular prior's input)
        sequences:
          walk_body40: {motion: ../shared/data/motions/cmu_12_01_walk.bvh, seed: 9101}
          knee_left_leg: {motion: jumping_jack, seed: 9104, markers: {count: 20, part: left_leg}}

A sequence's (and the dataset's) ``markers`` say how many markers, on which part, and what goes wrong while
recording, the fields of tasks/uuo/takes.py's MarkerFaults. By default a take is what an optical system
records: a marker is lost where fewer than two of the eight optical cameras see it past the body (``occlusion``),
its trajectory breaks now and then (``break_per_s``, per marker) and comes back under a new id after any loss
(``fragment``), and short-lived ghosts appear near the body (``ghosts_per_s``, per second of take); ``dropout``
adds hidden runs at random. ``occlusion: false, break_per_s: 0, ghosts_per_s: 0`` is the all-visible take of one
id per marker. The take is the studio's (tasks/studio/take.py). With ``video`` (a mapping
of tasks/uuo/video.py's VideoSpec fields, ``{}`` for its defaults) the take is also filmed in colour by one
still camera, as the variable ``video`` (frame, y, x, rgb), for the monocular prior (tasks/uuo/monocular.py).
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
from mocapflow.tasks.uuo import takes as uuo
from mocapflow.tasks.uuo.video import VideoError, VideoSpec, film

MARKER_DEFAULTS = {"count": 40, "part": "body"}
RENAMED = {"ghosts": "ghosts_per_s, a rate: ghost trajectories per second of take (0 for none)"}
_CAPTURES: BoundedCache[str, tuple] = BoundedCache(4)  # fingerprint -> (layout, captured), this process


def marker_options(raw: Mapping[str, Any] | None, where: str) -> tuple[int, str, uuo.MarkerFaults]:
    """(marker count, body part, capture faults) from a ``markers`` mapping, checked."""
    raw = {**MARKER_DEFAULTS, **(raw or {})}
    fields = {f.name: f for f in dataclasses.fields(uuo.MarkerFaults)}
    for key in raw:
        if key in RENAMED:
            raise CatalogError(f"{where}: markers field {key!r} is now {RENAMED[key]}")
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


def video_options(raw: Mapping[str, Any] | None, where: str) -> VideoSpec | None:
    """The video camera of a ``video`` mapping, checked; None without one."""
    if raw is None:
        return None
    if not isinstance(raw, Mapping):
        raise CatalogError(f"{where}: expected a mapping of video settings ({{}} for the defaults), got {raw!r}")
    hints = typing.get_type_hints(VideoSpec)
    unknown = sorted(set(raw) - set(hints))
    if unknown:
        raise CatalogError(f"{where}: unknown video field {unknown[0]!r}{did_you_mean(unknown[0], sorted(hints))}; "
                           f"fields: {sorted(hints)}")
    try:
        return VideoSpec(**{k: coerce(tuple(v) if isinstance(v, list) else v, hints[k], f"{where}.{k}")
                            for k, v in raw.items()})
    except VideoError as exc:
        raise CatalogError(f"{where}: {exc}") from exc


class StudioMarkersReader:
    """Unlabelled marker takes filmed on the studio's mesh body (UUO), as raw_markers with ground truth."""

    options = ("sequences", "defaults", "markers", "video")
    has_views = False

    @staticmethod
    def discover(catalog, dataset) -> list[SequenceInfo]:
        out = []
        for seq_id, where, extra, (spec, text, source) in sequence_specs(catalog, dataset, "studio_markers",
                                                                         mesh_only=True):
            markers = marker_options({**(dataset.options.get("markers") or {}), **(extra.get("markers") or {})},
                                     where)
            video = video_options(dataset.options.get("video"), f"{dataset.where}.video")
            fp = digest({"take": fingerprint(spec, text),
                         "markers": [markers[0], markers[1], dataclasses.asdict(markers[2])],
                         **({"video": dataclasses.asdict(video)} if video else {})})
            out.append(SequenceInfo(seq_id, (), frame_count(spec, text), fp,
                                    {"spec": spec, "source": source, "markers": markers, "video": video},
                                    image=(video.height, video.width) if video else None))
        return out

    @staticmethod
    def read(dataset, seq: SequenceInfo, start: int, stop: int):
        shot = take_for(seq)
        count, part, faults = seq.spec["markers"]

        def record():
            layout = uuo.layout(shot.body, np.random.default_rng([shot.spec.seed, 3]), count, part)
            return layout, uuo.record(shot.body, layout, shot.mesh.posed.vertices[:shot.n_frames], faults,
                                      np.random.default_rng([shot.spec.seed, 4]), shot.spec.fps)

        layout, captured = _CAPTURES.get_or_make(seq.fingerprint, record)
        out = uuo.marker_dataset(shot.body, layout, captured, shot.mesh, shot.spec.fps, start, stop)
        video = seq.spec.get("video")
        if video is None:
            return out
        frames = film(shot.mesh.posed.vertices[start:stop], shot.body.faces, shot.body.uv, video,
                      np.random.default_rng([shot.spec.seed, 5, start]))
        return out.assign(video=(("frame", "y", "x", "rgb"), frames)).assign_coords(
            rgb=np.array(["r", "g", "b"], dtype=object))

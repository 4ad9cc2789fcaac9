"""The studio filmed by DeepMoCap's IR-depth sensors: the dataset kind ``studio`` (raw sequences with ground truth)
and `mocapflow synth` (a sequence written as a raw-sequence zarr store).

    datasets:
      default:
        kind: studio
        layout: layouts/dmc.yaml          # optional camera layout file (else the DMC ring)
        defaults: {frames: 60, views: 3, noise: 1.0}
        sequences:
          jj_s1: {motion: jumping_jack, seed: 1, subject_height: 1.72}
          walk:  {motion: ../shared/data/motions/cmu_12_01_walk.bvh, seed: 7}

The sequences' fields are the studio's (systems/studio/specs.py); ``body: mesh`` films the take of
tasks/studio/take.py, ``capsule`` (the default) the template's primitives. ``out_of_view`` (warn, refuse or off)
says what a subject leaving a sensor's view does (specs.check_in_view).
"""

from __future__ import annotations

from mocapflow.pipeline.datasets import SequenceInfo
from mocapflow.pipeline.storage import check, init_zarr, write_zarr_region
from mocapflow.schemas import get_schema
from mocapflow.systems.studio.specs import (check_in_view, fingerprint, frame_count, read_layout, read_motion,
                                            sequence_specs, view_check)
from mocapflow.tasks.shared.cache import BoundedCache
from mocapflow.tasks.studio.cameras import HEIGHT, WIDTH
from mocapflow.tasks.deepmocap.film.synth import Rig, build_rig, synthesize
from mocapflow.tasks.studio.spec import SequenceSpec

_RIGS: BoundedCache[str, Rig] = BoundedCache(4)  # fingerprint -> rig, this process


def view_names(spec: SequenceSpec) -> tuple[str, ...]:
    """The sensors' names: a layout's own, else ``kinect0``, ``kinect1``, ..."""
    if spec.layout and "sensors" in spec.layout:
        return tuple(str(s.get("name", f"kinect{i}")) for i, s in enumerate(spec.layout["sensors"]))
    count = (spec.layout or {}).get("ring", {}).get("count", spec.views)
    return tuple(f"kinect{i}" for i in range(count))


class StudioReader:
    """Sequences synthesized by the studio and filmed by the DeepMoCap sensors, in the raw-sequence schema."""

    options = ("sequences", "defaults", "layout", "out_of_view")

    @staticmethod
    def discover(catalog, dataset) -> list[SequenceInfo]:
        layout = None
        if dataset.options.get("layout"):
            layout = read_layout(catalog.resolve_data_path(str(dataset.options["layout"]), dataset.where),
                                 dataset.where)
        check = view_check(dataset)
        out = []
        for seq_id, _, _, (spec, text, source) in sequence_specs(catalog, dataset, "studio", layout=layout):
            out.append(SequenceInfo(seq_id, view_names(spec), frame_count(spec, text), fingerprint(spec, text),
                                    {"spec": spec, "source": source, "out_of_view": check},
                                    image=(HEIGHT, WIDTH)))
        return out

    @staticmethod
    def read(dataset, seq: SequenceInfo, start: int, stop: int):
        return synthesize(rig_for(seq), start, stop)


def rig_for(info) -> Rig:
    """The sequence's rig, built once per worker process (cameras' rays and the room are reused)."""
    def build() -> Rig:
        source = info.spec["source"]
        rig = build_rig(info.spec["spec"], read_motion(source, f"sequence {info.id}") if source else None)
        joints = rig.joint_pos if isinstance(rig, Rig) else rig.take.posed.heads[:, rig.body.joint_bones()]
        check_in_view(info.id, [view.cam for view in rig.views], joints[:rig.n_frames],
                      info.spec.get("out_of_view", "warn"))
        return rig

    return _RIGS.get_or_make(info.fingerprint, build)


def write_sequence(rig: Rig, target: str, region_frames: int = 16) -> None:
    """Render a whole sequence into a raw-sequence zarr store, region by region."""
    schema = get_schema("raw_sequence")
    for start in range(0, rig.n_frames, region_frames):
        stop = min(start + region_frames, rig.n_frames)
        ds = synthesize(rig, start, stop)
        check(schema, ds, f"studio output {target}")
        if start == 0:
            init_zarr(target, schema, ds, rig.n_frames)
        write_zarr_region(target, ds, start, stop)

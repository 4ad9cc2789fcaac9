"""DeepMoCap (Chatzitofis et al., Sensors 2019): IR-depth sensors -> reflector masks and 3D flow -> two-stream FCN
heatmaps -> labelled 2D reflectors -> fused 3D markers -> tracks -> the body fitted to them (or a template skeleton).

Everything the system adds to the engine, declared in one place: its task specs (tasks.py), dataset kinds
(readers.py: zarr, images, dmc; film.py: ``studio``, the studio's takes filmed by its IR-depth sensors), the command
``mocapflow synth`` (cli.py), schemas, evaluator (evaluate.py), exporters (export.py: c3d, trc, bvh), report section
(report.py) and the reader of its trained weights. The kernels are in tasks/deepmocap (its filming: tasks/deepmocap/film).
"""

from mocapflow.pipeline.registry import Command, System
from mocapflow.schemas import fcn, markers, raw, skeleton, stages
from mocapflow.systems.deepmocap import compare, evaluate, export, readers, report, tasks
from mocapflow.systems.deepmocap.film import StudioReader
from mocapflow.tasks.deepmocap.training import weights_from_dataset

SYSTEM = System(
    name="deepmocap",
    description="IR-depth sensors, retro-reflective straps and patches, a two-stream FCN, fused and tracked 3D "
                "markers, a solved skeleton",
    tasks=tasks.TASKS,
    dataset_kinds={"zarr": readers.ZarrReader, "images": readers.ImageFolderReader, "dmc": readers.DeepMoCapReader,
                   "studio": StudioReader},
    schemas=(raw.RAW_SEQUENCE, stages.REFLECTOR_MASKS, stages.SCENE_FLOW, fcn.FCN_SAMPLES, fcn.FCN_WEIGHTS,
             fcn.HEATMAPS, fcn.REFLECTORS2D, markers.MARKERS3D, markers.SMOOTHED, skeleton.SKELETON, skeleton.POSES,
             skeleton.BODY_POSES),
    evaluators=(evaluate.EVALUATOR,),
    exporters=export.EXPORTERS,
    report=(report.SECTION,),
    weights={"fcn_weights": weights_from_dataset},
    compare=compare.COMPARER,
    commands={"synth": Command("mocapflow.systems.deepmocap.cli", "synth")},
)

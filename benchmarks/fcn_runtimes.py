"""The heatmaps network under other CPU runtimes: PyTorch eager (what the `heatmaps` stage runs) against ONNX
Runtime in float32 and in int8 (static quantization, per-channel weights, calibrated on crops of a
training-split exercise), and the first k refinement stages only (``HeatmapConfig.stages``). Per crop on one
core at a batch of 8, medians of interleaved calls, and how far each path's maps are from PyTorch float32's on
held-out crops (CMU walk, held-out subject seed, random layout):

    pip install -e ".[bench]"          # onnxruntime, onnx
    taskset -c 0 python benchmarks/fcn_runtimes.py [--weights FILE]   # default: the shipped weights

``peaks_moved`` (``_over_1_cell``): the share of (crop, reflector) peaks of PyTorch float32's maps (confidence
>= 0.3) whose cell moved (by more than one cell) in the other path's maps; ``max_abs_s``: the largest confidence
change. The 2D mAP of a path comes from the held-out catalog (``--set stages.heatmaps.params.stages=2``).
"""

from __future__ import annotations

import argparse
import io
import json
import os
import statistics
import time
from pathlib import Path

for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(var, "1")

import numpy as np  # noqa: E402
import torch  # noqa: E402

from mocapflow.formats.bvh import parse_bvh  # noqa: E402
from mocapflow.tasks.deepmocap.fcn import N_REFLECTORS, to_input  # noqa: E402
from mocapflow.tasks.deepmocap.flow import DisConfig, dis  # noqa: E402
from mocapflow.tasks.deepmocap.heatmaps import inference_model, network_inputs  # noqa: E402
from mocapflow.tasks.deepmocap.masks import MaskConfig, masks  # noqa: E402
from mocapflow.tasks.deepmocap.training import CropConfig  # noqa: E402
from mocapflow.tasks.shared.bvh_clip import BVHClip  # noqa: E402
from mocapflow.tasks.deepmocap.film.synth import build_rig, synthesize  # noqa: E402
from mocapflow.tasks.studio.spec import SequenceSpec

ROOT = Path(__file__).resolve().parents[1]
WEIGHTS = ROOT / "models" / "deepmocap_fcn.pt"
HELD_OUT = ROOT.parent / "shared" / "data" / "motions" / "cmu_12_01_walk.bvh"
BATCH = 8


def crops(spec: SequenceSpec, weights: dict, clip: BVHClip | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The `heatmaps` stage's network inputs for every view-frame of a studio take.  -> (n, s, s, 3) uint8 x2"""
    raw = synthesize(build_rig(spec, clip), 0, spec.frames)
    m, f = masks(raw[["depth", "ir"]], MaskConfig()), dis(raw, DisConfig())
    depth, flow, _ = network_inputs(m, f, CropConfig(**weights.get("crop", {})), weights["architecture"]["input_size"])
    return depth, flow


class _LastStage(torch.nn.Module):
    def __init__(self, model):
        super().__init__()
        self.model = model

    def forward(self, depth, flow):
        s, fields = self.model(depth, flow)[-1]
        return s, fields


def onnx_sessions(model, calibration: tuple[np.ndarray, np.ndarray]) -> dict:
    """ONNX Runtime sessions of ``model``'s last stage, float32 and int8 (calibrated on ``calibration`` crops)."""
    import onnxruntime as ort
    from onnxruntime.quantization import CalibrationDataReader, QuantFormat, QuantType, quantize_static
    from onnxruntime.quantization.shape_inference import quant_pre_process

    class Reader(CalibrationDataReader):
        def __init__(self):
            d, f = calibration
            self.batches = iter([{"depth": to_input(d[a:a + BATCH]).numpy(), "flow": to_input(f[a:a + BATCH]).numpy()}
                                 for a in range(0, len(d), BATCH)])

        def get_next(self):
            return next(self.batches, None)

    example = torch.zeros(BATCH, 3, model.arch.input_size, model.arch.input_size)
    buffer = io.BytesIO()
    torch.onnx.export(_LastStage(model).eval(), (example, example), buffer, input_names=["depth", "flow"],
                      output_names=["s", "l"], dynamic_axes={"depth": {0: "n"}, "flow": {0: "n"}}, opset_version=17,
                      dynamo=False)
    options = ort.SessionOptions()
    options.intra_op_num_threads = options.inter_op_num_threads = 1
    import tempfile

    with tempfile.TemporaryDirectory() as tmp:
        plain, prepared, int8 = (Path(tmp) / n for n in ("fcn.onnx", "fcn_pre.onnx", "fcn_int8.onnx"))
        plain.write_bytes(buffer.getvalue())
        quant_pre_process(str(plain), str(prepared))
        quantize_static(str(prepared), str(int8), Reader(), quant_format=QuantFormat.QDQ, per_channel=True,
                        activation_type=QuantType.QUInt8, weight_type=QuantType.QInt8)
        return {name: ort.InferenceSession(str(path), options, providers=["CPUExecutionProvider"])
                for name, path in (("onnxruntime_float32", plain), ("onnxruntime_int8", int8))}


def torch_path(model):
    def run(depth, flow):
        with torch.inference_mode():
            s, fields = model(to_input(depth, channels_last=True), to_input(flow, channels_last=True))[-1]
        return s.numpy(), fields.numpy()
    return run


def onnx_path(session):
    def run(depth, flow):
        return tuple(session.run(None, {"depth": to_input(depth).numpy(), "flow": to_input(flow).numpy()}))
    return run


def compare(reference: np.ndarray, other: np.ndarray) -> dict:
    """Peaks moved (by any cell, by more than one) and the largest confidence change between two (n, 27, g, g)
    confidence maps."""
    ref, oth = np.clip(reference[:, :N_REFLECTORS], 0, 1), np.clip(other[:, :N_REFLECTORS], 0, 1)
    n, r, g = ref.shape[:3]
    strong = ref.reshape(n, r, -1).max(axis=2) >= 0.3
    a = np.stack(np.unravel_index(ref.reshape(n, r, -1).argmax(axis=2), (g, g)), axis=-1)
    b = np.stack(np.unravel_index(oth.reshape(n, r, -1).argmax(axis=2), (g, g)), axis=-1)
    cells = np.abs(a - b).max(axis=-1)[strong]
    return {"peaks_moved": round(float((cells > 0).mean()), 4), "peaks_moved_over_1_cell": round(float((cells > 1).mean()), 4),
            "peaks": int(strong.sum()), "max_abs_s": round(float(np.abs(ref - oth).max()), 4)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--weights", type=Path, default=WEIGHTS, help="weights file (default: the shipped one)")
    torch.set_num_threads(1)
    weights = torch.load(parser.parse_args().weights, weights_only=True)
    held_out = crops(SequenceSpec("bvh", frames=24, seed=9100, random_layout=True, start_s=1.0), weights,
                     parse_bvh(HELD_OUT.read_text()))
    calibration = crops(SequenceSpec("jumping_jack", frames=16, seed=100, random_layout=True), weights)
    full = inference_model(weights)
    paths = {"torch_float32": torch_path(full)}
    for k in range(1, len(full.stages)):
        paths[f"torch_float32_stages_{k}"] = torch_path(inference_model(weights, k))
    paths.update({name: onnx_path(s) for name, s in onnx_sessions(full, calibration).items()})
    times = {name: [] for name in paths}
    maps = {name: [] for name in paths}
    depth, flow = held_out
    for a in range(0, len(depth) - BATCH + 1, BATCH):
        for name, run in paths.items():  # interleaved: every path sees the machine in the same state
            t = time.perf_counter()
            s, _ = run(depth[a:a + BATCH], flow[a:a + BATCH])
            times[name].append(1000 * (time.perf_counter() - t) / BATCH)
            maps[name].append(s)
    reference = np.concatenate(maps["torch_float32"])
    figures = {"cpu": _cpu_name(), "crops": len(reference), "batch": BATCH}
    for name in paths:
        figures[name] = {"ms_per_crop": round(statistics.median(times[name][1:]), 2),
                         **compare(reference, np.concatenate(maps[name]))}
    print(json.dumps(figures, indent=1))


def _cpu_name() -> str:
    for line in Path("/proc/cpuinfo").read_text().splitlines() if Path("/proc/cpuinfo").exists() else []:
        if line.startswith("model name"):
            return line.split(":", 1)[1].strip()
    return "unknown"


if __name__ == "__main__":
    main()

"""The two-stream FCN: stage outputs and their feedback (Eq. 1), ablation options, loss (Eq. 2-3), weights round-trip."""

import io
from pathlib import Path

import numpy as np
import pytest
import torch

from mocapflow.tasks.deepmocap import fcn


def test_stages_and_branches_have_the_declared_shapes():
    arch = fcn.FcnArchitecture(input_size=64, stream_width=8, fused_width=16, stage_width=16, stages=3)
    model = fcn.TwoStreamFCN(arch).eval()
    x = torch.zeros(2, 3, 64, 64)
    outputs = model(x, x)
    assert len(outputs) == 3
    for s, fields in outputs:
        assert s.shape == (2, 27, 16, 16) and fields.shape == (2, 52, 16, 16)
    # stage t > 1 reads (F, S_{t-1}, L_{t-1}): 16 + 27 + 52 channels
    assert model.stages[1].body[0][0].in_channels == 16 + 27 + 52
    assert model.stages[0].body[0][0].in_channels == 16


def test_ablations_drop_the_flow_stream_and_the_off_branch():
    depth_only = fcn.TwoStreamFCN(fcn.FcnArchitecture(input_size=32, stream_width=8, fused_width=8, stage_width=8,
                                                      stages=2, flow_stream=False, off_branch=False))
    assert depth_only.flow is None and depth_only.stages[1].off is None
    outputs = depth_only(torch.zeros(1, 3, 32, 32))
    assert outputs[-1][1] is None and outputs[-1][0].shape == (1, 27, 8, 8)
    assert depth_only.stages[1].body[0][0].in_channels == 8 + 27


def test_loss_sums_both_branches_over_stages():
    s = torch.ones(2, 27, 4, 4)
    fields = torch.zeros(2, 52, 4, 4)
    outputs = [(s, fields), (s, fields)]
    loss = fcn.stage_losses(outputs, torch.zeros_like(s), torch.ones_like(fields))
    assert float(loss) == pytest.approx(2 * (27 * 16 + 52 * 16))  # per sample: 2 stages x (S + L) squared errors


def test_weights_round_trip_through_plain_tensors():
    arch = fcn.FcnArchitecture(input_size=32, stream_width=8, fused_width=8, stage_width=8, stages=2)
    torch.manual_seed(0)
    model = fcn.TwoStreamFCN(arch).eval()
    buffer = io.BytesIO()
    torch.save(fcn.pack(model), buffer)
    buffer.seek(0)
    again = fcn.unpack(torch.load(buffer, weights_only=True))
    x = torch.from_numpy(np.random.default_rng(0).random((1, 3, 32, 32), np.float32))
    with torch.no_grad():
        torch.testing.assert_close(model(x, x)[-1][0], again(x, x)[-1][0])
    with pytest.raises(ValueError, match="mocapflow train"):
        fcn.unpack({"architecture": {"input_size": 32}, "state": {}})


def test_bfloat16_inference_gives_the_float32_maps_within_its_rounding():
    from mocapflow.tasks.deepmocap.heatmaps import HeatmapConfig, infer

    from mocapflow import models

    weights = torch.load(Path(models.__file__).parent / "deepmocap_fcn.pt", weights_only=True)  # the shipped weights
    model = fcn.unpack(weights)
    rng = np.random.default_rng(2)
    size = model.arch.input_size
    depth = rng.integers(0, 256, (3, size, size, 3), dtype=np.uint8)
    flow = np.full((3, size, size, 3), 128, np.uint8)
    s32, l32 = infer(model, depth, flow, 2, "float32")
    s16, l16 = infer(model, depth, flow, 2, "bfloat16")
    assert s16.dtype == np.float32 and s16.shape == s32.shape and l16.shape == l32.shape
    assert 0 < np.abs(s16 - s32).max() < 0.05 and np.abs(l16 - l32).max() < 0.05  # bfloat16 keeps 8 bits of mantissa
    with pytest.raises(ValueError, match="precision"):
        HeatmapConfig(precision="float16")


def test_inference_copy_gives_the_models_maps_and_is_built_once_per_weights():
    from mocapflow.tasks.deepmocap import heatmaps

    arch = fcn.FcnArchitecture(input_size=32, stream_width=8, fused_width=8, stage_width=8, stages=2)
    torch.manual_seed(3)
    model = fcn.TwoStreamFCN(arch)
    with torch.no_grad():  # batch norms that do something (eval-mode statistics away from 0 and 1), heads not zero
        for bn in (m for m in model.modules() if isinstance(m, torch.nn.BatchNorm2d)):
            bn.running_mean.uniform_(-0.5, 0.5), bn.running_var.uniform_(0.5, 2.0), bn.weight.uniform_(0.5, 1.5)
        for stage in model.stages:
            stage.confidence.weight.normal_(0.0, 0.3), stage.off.weight.normal_(0.0, 0.3)
    weights = fcn.pack(model.eval())
    fast = heatmaps.inference_model(weights)
    assert heatmaps.inference_model(weights) is fast  # the regions of a worker share it
    assert not any(isinstance(m, torch.nn.BatchNorm2d) for m in fast.modules())  # folded into the convolutions
    rng = np.random.default_rng(4)
    depth, flow = (rng.integers(0, 256, (3, 32, 32, 3), dtype=np.uint8) for _ in range(2))
    s_ref, l_ref = heatmaps.infer(fcn.unpack(weights), depth, flow, 2, "float32")
    s_fast, l_fast = heatmaps.infer(fast, depth, flow, 2, "float32")
    assert np.abs(s_ref).max() > 0.01 and np.abs(l_ref).max() > 0.01  # maps worth comparing
    np.testing.assert_allclose(s_fast, s_ref, atol=1e-5)
    np.testing.assert_allclose(l_fast, l_ref, atol=1e-5)
    x = fcn.to_input(depth, channels_last=True)
    assert x.is_contiguous(memory_format=torch.channels_last) and torch.equal(x, fcn.to_input(depth))


def test_bfloat16_without_native_support_is_named_in_a_warning(monkeypatch, caplog):
    from mocapflow.tasks.deepmocap import heatmaps

    arch = fcn.FcnArchitecture(input_size=32, stream_width=8, fused_width=8, stage_width=8, stages=2)
    model = fcn.TwoStreamFCN(arch).eval()
    crops = np.full((1, 32, 32, 3), 128, np.uint8)
    monkeypatch.setattr(heatmaps, "native_bfloat16", lambda: False)
    heatmaps._warn_emulated.cache_clear()
    with caplog.at_level("WARNING", logger="mocapflow.tasks.deepmocap.heatmaps"):
        heatmaps.infer(model, crops, crops, 1, "float32")
        assert not caplog.records  # float32 never warns
        for _ in range(3):
            heatmaps.infer(model, crops, crops, 1, "bfloat16")
    assert len(caplog.records) == 1  # once per process, not once per region
    assert "precision: auto" in caplog.text and "AVX512-BF16" in caplog.text


def test_the_heatmaps_run_in_the_precision_the_cpu_serves_best_by_default():
    from mocapflow.tasks.deepmocap import heatmaps

    assert heatmaps.HeatmapConfig().precision == "auto"  # tasks/shared/precision.py resolves it


def test_half_rounds_like_numpy_below_the_normal_range():
    from mocapflow.tasks.deepmocap.heatmaps import half

    x = np.concatenate([np.geomspace(1e-9, 1.0, 5000), -np.geomspace(1e-9, 1.0, 5000), [0.0, 65504.0]])
    x = x.astype(np.float32)
    np.testing.assert_array_equal(half(x), x.astype(np.float16))  # subnormals included
    assert half(x).dtype == np.float16

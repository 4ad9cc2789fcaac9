"""The suit's networks prepared for inference (tasks/suit/networks.py ``for_inference``): batch normalisation
folded, each ReLU after its max pool, channels-last weights; the same outputs as the trained networks to float
rounding, the reading of the shipped code networks unchanged, and in bfloat16 the same on synthetic crops."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch
from torch import nn

from mocapflow.tasks.suit import codes as cd
from mocapflow.tasks.suit.net_configs import CodeNetConfig, CornerNetConfig
from mocapflow.tasks.shared.precision import amx_tiles, resolve_precision
from mocapflow.tasks.suit.networks import CornerdetNet, RecogNet, RejectorNet, for_inference

WEIGHTS = Path(__file__).resolve().parents[3] / "models" / "suit_codes.pt"


def _trained_looking(net: nn.Module, seed: int) -> nn.Module:
    """``net`` in eval mode with batch normalisation statistics and affine maps away from the identity."""
    gen = torch.Generator().manual_seed(seed)
    for m in net.modules():
        if isinstance(m, nn.BatchNorm2d):
            m.running_mean.copy_(torch.randn(m.num_features, generator=gen) * 0.3)
            m.running_var.copy_(torch.rand(m.num_features, generator=gen) + 0.5)
            m.weight.data.copy_(torch.rand(m.num_features, generator=gen) + 0.5)
            m.bias.data.copy_(torch.randn(m.num_features, generator=gen) * 0.2)
    return net.eval()


@pytest.mark.parametrize("make, shape", [
    (lambda: CornerdetNet(CornerNetConfig()), (3, 1, 76, 84)),
    (lambda: RejectorNet(CodeNetConfig()), (5, 1, cd.CROP, cd.CROP)),
    (lambda: RecogNet(CodeNetConfig(widths=(24, 48, 64, 96), hidden=192, pool=2)), (5, 1, cd.CROP, cd.CROP)),
])
def test_a_prepared_network_computes_what_the_trained_one_does(make, shape):
    torch.manual_seed(0)
    net = _trained_looking(make(), 1)
    before = {k: v.clone() for k, v in net.state_dict().items()}
    fast = for_inference(net)
    x = torch.rand(shape, generator=torch.Generator().manual_seed(2))
    with torch.inference_mode():
        want, got = net(x), fast(x)
    for a, b in zip(want if isinstance(want, tuple) else (want,), got if isinstance(got, tuple) else (got,)):
        np.testing.assert_allclose(b.numpy(), a.numpy(), rtol=1e-4, atol=1e-4 * float(a.abs().max()))
    assert not any(isinstance(m, nn.BatchNorm2d) for m in fast.modules())
    assert all(torch.equal(before[k], v) for k, v in net.state_dict().items())  # the trained one untouched
    assert for_inference(fast) is fast
    with pytest.raises(ValueError, match="eval mode"):
        for_inference(make())


@pytest.fixture(scope="module")
def crops_and_nets():
    torch.set_num_threads(1)
    rejector, recog = cd.nets_from_weights(torch.load(WEIGHTS, weights_only=True))
    config = cd.SynthConfig(square_px=(24.0, 45.0), noise=(1.0, 3.0), blur=(0.0, 0.8), negative_share=0.25)
    return cd.synthetic_quads(300, config, np.random.default_rng(4243)), rejector, recog


def test_the_shipped_code_networks_read_the_same_prepared_and_in_one_call_or_many(crops_and_nets):
    s, rejector, recog = crops_and_nets
    plain = cd.read_crops(s.crops, rejector, recog, cd.ReadConfig(precision="float32"))
    fast = (for_inference(rejector), for_inference(recog))
    for batch in (512, 7):  # all the image's crops in one call, or in batches
        read = cd.read_crops(s.crops, *fast, cd.ReadConfig(precision="float32", batch=batch))
        np.testing.assert_array_equal(read.accepted, plain.accepted)
        np.testing.assert_array_equal(read.rotation, plain.rotation)
        np.testing.assert_array_equal(read.code, plain.code)
        np.testing.assert_allclose(read.confidence, plain.confidence, atol=1e-4)
    assert 0.6 < plain.accepted.mean() < 0.9


def test_bfloat16_reads_what_float32_reads(crops_and_nets):
    s, rejector, recog = crops_and_nets
    fast = (for_inference(rejector), for_inference(recog))
    full = cd.read_crops(s.crops, *fast, cd.ReadConfig(precision="float32"))
    low = cd.read_crops(s.crops, *fast, cd.ReadConfig(precision="bfloat16"))
    assert (low.accepted == full.accepted).mean() >= 0.99  # measured: all 300
    both = low.accepted & full.accepted
    np.testing.assert_array_equal(low.code[both], full.code[both])
    np.testing.assert_array_equal(low.rotation[both], full.rotation[both])
    assert np.abs(low.confidence - full.confidence).max() < 0.05  # measured: 0.016


def test_precision_auto_is_bfloat16_only_with_amx_tiles():
    assert resolve_precision("float32") == "float32" and resolve_precision("bfloat16") == "bfloat16"
    assert resolve_precision("auto") == ("bfloat16" if amx_tiles() else "float32")
    with pytest.raises(cd.CodeError, match="precision"):
        cd.ReadConfig(precision="half")

"""The networks of the suit's 2D chain (Chen et al. 2021): CornerdetNet (§3.1) and RejectorNet / RecogNet (§3.2).

Their own module so that the chain's stage modules (corners, codes) and the engine's planning import without
torch; the stages import these when they run.
"""

from __future__ import annotations

import copy

import torch
from torch import nn
from torch.nn.utils.fusion import fuse_conv_bn_eval

from mocapflow.tasks.suit.net_configs import N_CHARS, CodeNetConfig, CornerNetConfig
from mocapflow.tasks.suit.quads import CROP

CORNERDET = CornerNetConfig()
REJECTOR = CodeNetConfig()
RECOG = CodeNetConfig(widths=(24, 48, 64, 96), hidden=192, pool=2)


class CornerdetNet(nn.Module):
    """Fig. 5c, Chen et al. 2021, fully convolutional: (n, 1, 8h + 12, 8w + 12) grey in [0, 1] -> (n, 3, h, w) with
    output (i, j) a function of input rows [8i, 8i + 20) and columns [8j, 8j + 20) only: channel 0 the presence
    logit, 1-2 the corner's (x, y) in the cell normalised to [0, 1]. (Batch normalisation, once trained, is a
    per-channel affine map and keeps this.)"""

    def __init__(self, config: CornerNetConfig = CORNERDET):
        super().__init__()
        w1, w2, w3, w4 = config.widths
        self.config = config
        shapes = ((1, w1, 4, 2), (w1, w2, 3, 2), (w2, w3, 2, 2), (w3, w4, 2, 1), (w4, config.hidden, 1, 1))
        # receptive fields 4, 8, 12, 20, 20 at strides 2, 4, 8, 8, 8: one output per 8 x 8 cell with 6-px margins
        layers: list[nn.Module] = []
        for c_in, c_out, k, s in shapes:
            layers.append(nn.Conv2d(c_in, c_out, k, stride=s, bias=not config.batch_norm))
            layers += [nn.BatchNorm2d(c_out), nn.ReLU()] if config.batch_norm else [nn.ReLU()]
        self.layers = nn.Sequential(*layers, nn.Conv2d(config.hidden, 3, 1))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.layers(x - 0.5)


class _Trunk(nn.Module):
    """(n, 1, 104, 104) grey in [0, 1] -> (n, hidden) features."""

    def __init__(self, config: CodeNetConfig):
        super().__init__()
        layers: list[nn.Module] = [nn.AvgPool2d(config.pool)]  # 104 -> 26
        c_in, side = 1, CROP // config.pool
        for width in config.widths:
            layers += [nn.Conv2d(c_in, width, 3, padding=1, bias=False), nn.BatchNorm2d(width), nn.ReLU(),
                       nn.MaxPool2d(2)]
            c_in, side = width, side // 2
        self.features = nn.Sequential(*layers)
        self.hidden = nn.Sequential(nn.Flatten(), nn.Linear(c_in * side * side, config.hidden), nn.ReLU())

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.hidden(self.features(x))


class RejectorNet(nn.Module):
    """(n, 1, 104, 104) -> (n,) logit: a coded white square of the suit (§3.2)."""

    def __init__(self, config: CodeNetConfig = REJECTOR):
        super().__init__()
        self.config = config
        self.trunk = _Trunk(config)
        self.out = nn.Linear(config.hidden, 1)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.out(self.trunk(x))[:, 0]


class RecogNet(nn.Module):
    """(n, 1, 104, 104) -> rotation logits (n, 4), first and second character logits (n, 25) each (§3.2)."""

    def __init__(self, config: CodeNetConfig = RECOG):
        super().__init__()
        self.config = config
        self.trunk = _Trunk(config)
        self.out = nn.Linear(config.hidden, 4 + 2 * N_CHARS)

    def forward(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        y = self.out(self.trunk(x))
        return y[:, :4], y[:, 4:4 + N_CHARS], y[:, 4 + N_CHARS:]


# ------------------------------------------------------------------------------------------------------ inference

def for_inference(net: nn.Module) -> nn.Module:
    """A copy of a suit network (CornerdetNet, RejectorNet or RecogNet, in eval mode) that computes the same outputs
    faster on a CPU, differing by float rounding only: every batch normalisation folded into the convolution before
    it (its eval-mode affine map), each ReLU moved after the max pool that follows it (they commute: the max of the
    ReLUs is the ReLU of the max, on a quarter of the values) and the weights in channels-last layout (in torch's
    default one the unfused ReLU, batch normalisation and max pool over full-size maps cost more than the
    convolutions). Measured on one core: RecogNet reads a crop in 0.43 ms instead of 1.5 ms, CornerdetNet's pass
    over an image is 17-24 % faster (docs/suit.md). A network already prepared is returned as it is; training and
    ``pack_state`` need the original."""
    if getattr(net, "for_inference", False):
        return net
    if net.training:
        raise ValueError("for_inference needs a network in eval mode (its batch normalisation's running statistics)")
    fast = copy.deepcopy(net)
    _fold_children(fast)
    fast.for_inference = True
    return fast.to(memory_format=torch.channels_last)


def _fold_children(module: nn.Module) -> None:
    """In place, every Sequential under ``module`` folded (:func:`folded`)."""
    for name, child in list(module.named_children()):
        if isinstance(child, nn.Sequential):
            setattr(module, name, nn.Sequential(*folded(child)))
        _fold_children(getattr(module, name))


def folded(layers: nn.Sequential) -> list[nn.Module]:
    """Conv2d + BatchNorm2d -> the fused Conv2d; ReLU + MaxPool2d -> MaxPool2d + ReLU (in place: the pool's output
    is its own); other layers as they are."""
    out: list[nn.Module] = []
    for layer in layers:
        if isinstance(layer, nn.BatchNorm2d) and out and isinstance(out[-1], nn.Conv2d):
            out[-1] = fuse_conv_bn_eval(out[-1], layer)
        elif isinstance(layer, nn.MaxPool2d) and out and isinstance(out[-1], nn.ReLU):
            out[-1:] = [layer, nn.ReLU(inplace=True)]
        else:
            out.append(layer)
    return out



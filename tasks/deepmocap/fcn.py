"""The two-stream multi-stage fully convolutional network (DeepMoCap §3.3.1, Figure 4).

Two streams, colorized depth I_CD and colorized 3D optical flow I_F, each through its own
convolutional feature extractor (no pretrained VGG-19 exists here, so both are small and trained from
scratch); early fusion by concatenation F = F_OF ⊕ F_D; then T stages of CPM-style refinement with
two branches, confidence maps S (26 reflectors + background) and optical flow fields L (26 x 2).
Stage 1 sees F; stage t > 1 sees (F, S_{t-1}, L_{t-1}) (Eq. 1). Every stage is supervised with an
L2 loss on both branches (Eq. 2-3). Dilated 3x3 convolutions stand in for the paper's 7x7 ones: the
same receptive field at a fraction of the cost on a CPU. Every stage's output heads start at zero
(background map at one), so the first iterations learn features instead of undoing random maps: in
a development comparison with the same 8 CPU-minutes of training, randomly initialized heads put 18 % of the validation peaks
within 1.5 cells of the truth, zeroed ones 94 %.

Ablations of §5.1 from the same class: ``flow_stream=False`` is [14] (depth only, no OFF branch when
``off_branch=False`` too), ``off_branch=False`` alone is "[14] + 3D OF".
"""

from __future__ import annotations

import copy
from dataclasses import asdict, dataclass

import numpy as np
import torch
from torch import nn
from torch.nn.utils.fusion import fuse_conv_bn_eval

N_REFLECTORS = 26


@dataclass(frozen=True)
class FcnArchitecture:
    """Width, depth, stages and input size of the network; stored with its weights."""

    input_size: int = 128  # square crop, pixels
    stream_width: int = 32  # channels of each stream's features
    fused_width: int = 64  # channels of F
    stage_width: int = 64
    stages: int = 3  # T
    flow_stream: bool = True
    off_branch: bool = True
    stride: int = 4  # output grid: input_size / stride cells a side

    def __post_init__(self):
        if self.input_size % self.stride or self.stride != 4:
            raise ValueError(f"input_size ({self.input_size}) must be a multiple of the stride 4")
        if self.stages < 1:
            raise ValueError(f"stages must be >= 1, got {self.stages}")

    @property
    def grid(self) -> int:
        return self.input_size // self.stride


def _conv(cin: int, cout: int, *, stride: int = 1, dilation: int = 1) -> nn.Sequential:
    return nn.Sequential(nn.Conv2d(cin, cout, 3, stride=stride, padding=dilation, dilation=dilation, bias=False),
                         nn.BatchNorm2d(cout), nn.ReLU(inplace=True))


def _stream(width: int) -> nn.Sequential:
    """One input stream's feature extractor: 3 x H x W -> width x H/4 x W/4."""
    half = width // 2
    return nn.Sequential(_conv(3, half, stride=2), _conv(half, half), _conv(half, width, stride=2),
                         _conv(width, width), _conv(width, width, dilation=2))


class _Stage(nn.Module):
    """One refinement stage: dilated convolutions, then the S branch (and the L branch)."""

    def __init__(self, cin: int, width: int, off_branch: bool):
        super().__init__()
        self.body = nn.Sequential(_conv(cin, width), _conv(width, width, dilation=2), _conv(width, width, dilation=4),
                                  _conv(width, width, dilation=8), _conv(width, width))
        self.confidence = nn.Conv2d(width, N_REFLECTORS + 1, 1)
        self.off = nn.Conv2d(width, 2 * N_REFLECTORS, 1) if off_branch else None
        for head in (self.confidence, self.off):  # start from S = background, L = 0: the empty image's answer
            if head is not None:
                nn.init.zeros_(head.weight)
                nn.init.zeros_(head.bias)
        with torch.no_grad():
            self.confidence.bias[N_REFLECTORS] = 1.0

    def forward(self, x):
        h = self.body(x)
        return self.confidence(h), (self.off(h) if self.off is not None else None)


class TwoStreamFCN(nn.Module):
    def __init__(self, arch: FcnArchitecture):
        super().__init__()
        self.arch = arch
        self.depth = _stream(arch.stream_width)
        self.flow = _stream(arch.stream_width) if arch.flow_stream else None
        streams = 2 if arch.flow_stream else 1
        self.fuse = _conv(streams * arch.stream_width, arch.fused_width)
        fed_back = N_REFLECTORS + 1 + (2 * N_REFLECTORS if arch.off_branch else 0)
        self.stages = nn.ModuleList(
            [_Stage(arch.fused_width + (fed_back if t else 0), arch.stage_width, arch.off_branch)
             for t in range(arch.stages)])

    def forward(self, depth: torch.Tensor, flow: torch.Tensor | None = None):
        """(batch, 3, H, W) float in [-0.5, 0.5] each -> per stage: S (batch, 27, H/4, W/4), L (batch, 52, H/4, W/4)"""
        features = [self.depth(depth)]
        if self.flow is not None:
            features.insert(0, self.flow(flow))
        fused = self.fuse(torch.cat(features, dim=1))  # F = F_OF ⊕ F_D
        outputs, x = [], fused
        for stage in self.stages:
            s, fields = stage(x)
            outputs.append((s, fields))
            x = torch.cat([fused, s] + ([fields] if fields is not None else []), dim=1)  # Eq. (1): (F, S_{t-1}, L_{t-1})
        return outputs


def stage_losses(outputs, s_target: torch.Tensor, l_target: torch.Tensor | None,
                 weight: torch.Tensor | None = None) -> torch.Tensor:
    """Sum over stages of the L2 losses of both branches, per sample.   # Eq. (2)-(3), DeepMoCap

    ``weight`` (batch, 1, h, w), optional, scales each cell's squared error (a weighted L2 that
    makes the few reflector cells count against the many background ones).
    """
    w = 1.0 if weight is None else weight
    total = 0.0
    for s, fields in outputs:
        total = total + (w * (s - s_target) ** 2).sum() / len(s)
        if fields is not None and l_target is not None:
            total = total + (w * (fields - l_target) ** 2).sum() / len(fields)
    return total


def to_input(image: np.ndarray | torch.Tensor, channels_last: bool = False) -> torch.Tensor:
    """uint8 (batch, y, x, 3) -> float (batch, 3, y, x) in [-0.5, 0.5], in torch's channels-last memory layout
    (the images' own) if asked, else contiguous"""
    x = torch.as_tensor(image).permute(0, 3, 1, 2)
    return (x if channels_last else x.contiguous()).float().div_(255.0).sub_(0.5)


def for_inference(model: TwoStreamFCN) -> TwoStreamFCN:
    """A copy of ``model`` (in eval mode) that computes the same maps faster on a CPU (1.3x in bfloat16, at a
    batch of 8 crops on one core): every batch normalization folded into the convolution before it (its
    eval-mode affine map) and the weights in channels-last layout, for inputs from ``to_input(...,
    channels_last=True)``. The maps differ from ``model``'s by float rounding only."""
    fast = copy.deepcopy(model).eval()
    for block in fast.modules():
        if isinstance(block, nn.Sequential) and len(block) == 3 and isinstance(block[1], nn.BatchNorm2d):
            block[0], block[1] = fuse_conv_bn_eval(block[0], block[1]), nn.Identity()  # see _conv
    return fast.to(memory_format=torch.channels_last)


# Weights travel as plain tensors plus plain metadata (torch.load(weights_only=True) reads them back).

def pack(model: TwoStreamFCN) -> dict:
    return {"architecture": asdict(model.arch), "state": {k: v.detach().cpu() for k, v in model.state_dict().items()}}


def unpack(weights: dict) -> TwoStreamFCN:
    """The network described by ``weights`` (from :func:`pack`), in eval mode."""
    try:
        arch = FcnArchitecture(**weights["architecture"])
        model = TwoStreamFCN(arch)
        model.load_state_dict(weights["state"])
    except (KeyError, TypeError, RuntimeError) as exc:
        raise ValueError(f"not a two-stream FCN weights file ({exc}); create one with `mocapflow train`") from exc
    return model.eval()

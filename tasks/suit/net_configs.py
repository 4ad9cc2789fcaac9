"""The shapes of the suit's networks and the errors of their stages, without torch: what the networks
(networks.py) are built from and what the chain's stage modules (corners.py, codes.py) check, so neither imports
the other's module (Chen et al. 2021, §6)."""

from __future__ import annotations

from dataclasses import dataclass

from mocapflow.tasks.suit.pattern import ALPHABET
from mocapflow.tasks.suit.quads import CROP

N_CHARS = len(ALPHABET)


class CornerError(ValueError):
    """An image, truth or setting the corner detector cannot work with."""


class CodeError(ValueError):
    """Crops, samples or settings the code networks cannot use."""


@dataclass(frozen=True)
class CornerNetConfig:
    """CornerdetNet's widths: four convolutions (4x4/2, 3x3/2, 2x2/2, 2x2/1: receptive field 20, stride 8), then
    a 1x1 hidden layer and the 1x1 output (logit, u, v); batch normalisation after each hidden convolution."""

    widths: tuple[int, int, int, int] = (24, 48, 96, 96)
    hidden: int = 96
    batch_norm: bool = True

    def __post_init__(self):
        if len(self.widths) != 4 or min(self.widths) < 1 or self.hidden < 1:
            raise CornerError(f"CornerdetNet needs four positive widths and a positive hidden width, got "
                              f"widths={self.widths}, hidden={self.hidden}")


@dataclass(frozen=True)
class CodeNetConfig:
    """A VGG-like trunk on the crop average-pooled by ``pool``: per width a 3x3 convolution, batch normalisation,
    ReLU and a 2x2 max pool; then a hidden fully connected layer."""

    widths: tuple[int, ...] = (16, 32, 64)
    hidden: int = 64
    pool: int = 4  # 104 -> 26

    def __post_init__(self):
        if not self.widths or min(self.widths) < 1 or self.hidden < 1 or CROP % self.pool:
            raise CodeError(f"code networks need positive widths and hidden size and a pool dividing {CROP}, got "
                            f"{self.widths}, {self.hidden}, {self.pool}")

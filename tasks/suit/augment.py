"""Training helpers the suit's networks share (Chen et al. 2021, §4.2): seeded generators, Adam with a cosine
schedule, the augmentations of a batch of crops (exact quarter turns and flips, contrast, brightness, gamma,
noise, blur) and the training loop, checkpointed and resumable (:func:`fit`). torch is imported when they run,
never when planning."""

from __future__ import annotations

import json
from dataclasses import dataclass
from typing import TYPE_CHECKING, Callable

import numpy as np

from mocapflow.tasks.shared.progress import TrainingProgress
from mocapflow.tasks.suit.crop_pool import CropPool

if TYPE_CHECKING:
    import torch


@dataclass(frozen=True)
class Augment:
    """§4.2, Chen et al. 2021: intensity perturbations (contrast, brightness, gamma), noise and blur per crop,
    drawn uniformly in these ranges; plus an exact quarter turn / flip of each crop with its target."""

    contrast: tuple[float, float] = (0.5, 1.3)  # about the crop's mean
    brightness: float = 0.12  # +- this, in [0, 1] grey
    gamma: tuple[float, float] = (0.6, 1.6)
    noise: tuple[float, float] = (0.0, 0.03)  # Gaussian sigma, [0, 1] grey
    blur: tuple[float, float] = (0.0, 1.2)  # Gaussian sigma, px, for a ``blur_share`` of the crops
    blur_share: float = 0.5


def seeded(seed: int, stream: int) -> tuple[torch.Generator, np.random.Generator, str]:
    """A training's randomness from its seed (torch's global one too) and the device it runs on: the GPU when
    present (batches are still drawn on the CPU)."""
    import torch

    torch.manual_seed(seed)
    return (torch.Generator().manual_seed(seed), np.random.default_rng([seed, stream]),
            "cuda" if torch.cuda.is_available() else "cpu")


def streams_state(gen: torch.Generator, rng: np.random.Generator) -> dict:
    """A training's two generators' states, as a checkpoint keeps them (a tensor and a JSON string)."""
    return {"torch_rng": gen.get_state(), "numpy_rng": json.dumps(rng.bit_generator.state)}


def restore_streams(saved: dict, gen: torch.Generator, rng: np.random.Generator) -> None:
    """Set the generators to a checkpoint's states (nothing for a fresh run: ``saved`` empty)."""
    if not saved:
        return
    gen.set_state(saved["torch_rng"])
    rng.bit_generator.state = json.loads(saved["numpy_rng"])


def adam_cosine(params: list, learning_rate: float, iterations: int):
    """Adam with a cosine decay to 1 % of the learning rate over the iterations.  -> optimizer, scheduler"""
    import torch

    opt = torch.optim.Adam(params, lr=learning_rate)
    return opt, torch.optim.lr_scheduler.CosineAnnealingLR(opt, iterations, eta_min=0.01 * learning_rate)


def dihedral(x: torch.Tensor, position: torch.Tensor, gen: torch.Generator) -> tuple[torch.Tensor, torch.Tensor]:
    """A random one of the 8 exact quarter turns and flips per crop, its target turned with it (the cell is
    central, so (u, v) -> (v, u) on a transpose and u -> 1 - u on a flip of x).  (n, 1, 20, 20), (n, 2)"""
    import torch

    n = len(x)
    t, fx, fy = (torch.rand(n, generator=gen) < 0.5 for _ in range(3))
    x = torch.where(t[:, None, None, None], x.transpose(-1, -2), x)
    p = torch.where(t[:, None], position.flip(-1), position)
    x = torch.where(fx[:, None, None, None], x.flip(-1), x)
    p = torch.stack([torch.where(fx, 1 - p[:, 0], p[:, 0]), p[:, 1]], dim=1)
    x = torch.where(fy[:, None, None, None], x.flip(-2), x)
    p = torch.stack([p[:, 0], torch.where(fy, 1 - p[:, 1], p[:, 1])], dim=1)
    return x, p


def augment_crops(x: torch.Tensor, aug: Augment, gen: torch.Generator) -> torch.Tensor:
    """§4.2, Chen et al. 2021: blur, contrast, brightness, gamma and noise per crop, then 8-bit levels.
    (n, 1, 20, 20) in [0, 1] -> same"""
    import torch

    n = len(x)

    def draw(lo: float, hi: float) -> torch.Tensor:  # drawn on the CPU (the generator's), used where x is
        return (lo + (hi - lo) * torch.rand(n, generator=gen))[:, None, None, None].to(x.device)

    sigma = draw(*aug.blur) * (torch.rand(n, 1, 1, 1, generator=gen) < aug.blur_share).to(x.device)
    x = _gaussian_blur(x, sigma.flatten())
    mean = x.mean(dim=(2, 3), keepdim=True)
    x = (x - mean) * draw(*aug.contrast) + mean + draw(-aug.brightness, aug.brightness)
    x = x.clamp(0, 1) ** draw(*aug.gamma)
    x = x + draw(*aug.noise) * torch.randn(x.shape, generator=gen).to(x.device)
    return torch.round(x.clamp(0, 1) * 255) / 255


def _gaussian_blur(x: torch.Tensor, sigma: torch.Tensor, radius: int = 3) -> torch.Tensor:
    """Per-crop separable Gaussian blur (sigma 0: unchanged), replicated borders.  (n, 1, y, x), (n,) -> same"""
    import torch
    from torch.nn import functional as F

    t = torch.arange(-radius, radius + 1, dtype=x.dtype, device=x.device)
    k = torch.exp(-0.5 * (t[None] / sigma.clamp(min=1e-3)[:, None]) ** 2)  # (n, 2r + 1)
    k = k / k.sum(dim=1, keepdim=True)
    n = len(x)
    y = F.pad(x.transpose(0, 1), (radius, radius, radius, radius), mode="replicate")  # (1, n, y + 2r, x + 2r)
    y = F.conv2d(y, k[:, None, None, :], groups=n)
    y = F.conv2d(y, k[:, None, :, None], groups=n)
    return y.transpose(0, 1)


@dataclass
class Fitted:
    """What a training's loop leaves besides its networks: the loss of every iteration and the seconds it took
    (over every run of a resumed training), and where it ran."""

    losses: list[float]
    seconds: float
    device: str


def fit(modules: dict, batch_loss: Callable[[], torch.Tensor], *, optimizer, schedule, iterations: int,
        pool: CropPool, streams: tuple[torch.Generator, np.random.Generator], device: str, checkpoint=None,
        checkpoint_every: int = 500) -> Fitted:
    """The loop of a suit training: before each batch the pool turns; ``batch_loss()`` draws a batch (from the
    pool, with the generators ``streams``) and gives its loss; Adam steps. With a ``checkpoint`` (``load()``,
    ``save(dict)``), the networks, optimizer, schedule, generators and the pool's resident samples are saved every
    ``checkpoint_every`` iterations and a saved state is continued from: the networks end as an uninterrupted run
    would. The networks end on the CPU, in eval mode."""
    import torch

    gen, rng = streams
    run = TrainingProgress.start(checkpoint.load() if checkpoint is not None else None, modules, optimizer, schedule,
                                 iterations)
    restore_streams(run.saved, gen, rng)
    if run.saved:
        pool.restore(run.saved["resident"].tolist())
    for module in modules.values():
        module.train()
    while run.iteration < iterations:
        pool.turn(rng)
        loss = batch_loss()
        optimizer.zero_grad(set_to_none=True)
        loss.backward()
        optimizer.step()
        schedule.step()
        run.step(loss.item())
        if checkpoint is not None and run.due(checkpoint_every):
            checkpoint.save(run.state(modules, optimizer, schedule, resident=torch.as_tensor(pool.resident),
                                      **streams_state(gen, rng)))
    for module in modules.values():
        module.cpu().eval()
    return Fitted(run.losses, round(run.seconds(), 1), device)

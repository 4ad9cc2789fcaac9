"""Where a training stands, and the state its checkpoint keeps, for every training of the project.

A training saves ``TrainingProgress.state(...)`` through the engine's checkpoint (``save(dict)``) every so many
iterations and, started again, continues from ``TrainingProgress.start(checkpoint.load(), ...)``: its networks,
optimizer and schedule restored, its losses and seconds so far kept, and whatever else it saved (its generators'
states, the samples it held) in ``saved``. Only tensors, numbers, strings, lists and dicts go in, which is what
``torch.load(..., weights_only=True)`` reads back.
"""

from __future__ import annotations

import logging
import time
from typing import Mapping

import numpy as np

log = logging.getLogger(__name__)


class CheckpointMismatch(ValueError):
    """A checkpoint that is not of this training (another schedule): the cache key should have kept it apart."""


class TrainingProgress:
    """The next iteration, the losses so far, the seconds of this run and of the earlier ones; logs its progress
    every ``log_every`` iterations."""

    def __init__(self, iteration: int, losses: list[float], earlier_s: float, total: int,
                 saved: dict | None = None, log_every: int = 100):
        self.iteration, self.losses, self.earlier_s, self.total = iteration, losses, earlier_s, total
        self.saved = saved or {}
        self.started, self.resumed_at, self.log_every = time.perf_counter(), iteration, log_every

    @classmethod
    def start(cls, state: dict | None, modules: Mapping, optimizer, schedule, iterations: int,
              log_every: int = 100) -> "TrainingProgress":
        """A fresh run, or the one ``state`` saved: each of ``modules`` (name -> network, as saved), the optimizer
        and the schedule restored."""
        if state is None:
            return cls(0, [], 0.0, iterations, log_every=log_every)
        if int(state["iterations"]) != iterations:  # a cache key covers it; a stale file would be a bug
            raise CheckpointMismatch(f"checkpoint of a {int(state['iterations'])}-iteration training, this one has "
                                     f"{iterations}; delete the checkpoint")
        missing = [name for name in modules if name not in state]
        if missing:
            raise CheckpointMismatch(f"checkpoint lacks the network(s) {', '.join(missing)} this training has; "
                                     "delete the checkpoint")
        for name, module in modules.items():
            module.load_state_dict(state[name])
        optimizer.load_state_dict(state["optimizer"])
        schedule.load_state_dict(state["schedule"])
        run = cls(int(state["iteration"]), [float(x) for x in state["losses"]], float(state["seconds"]), iterations,
                  saved=state, log_every=log_every)
        log.info("resuming the training at iteration %d/%d (%.0f s trained before)", run.iteration, run.total,
                 run.earlier_s)
        return run

    def step(self, loss: float) -> None:
        self.losses.append(loss)
        done, self.iteration = self.iteration, self.iteration + 1
        if done % self.log_every == 0 or self.iteration == self.total:
            rate = (self.iteration - self.resumed_at) / max(time.perf_counter() - self.started, 1e-9)
            log.info("iteration %d/%d: loss %.3f (%.0f s, %.2f it/s, %.0f s to go)", done, self.total,
                     np.mean(self.losses[-self.log_every:]), self.seconds(), rate, (self.total - self.iteration) / rate)

    def due(self, every: int) -> bool:
        """Whether a checkpoint is due now: every ``every`` iterations, never after the last (the result is)."""
        return self.iteration % every == 0 and self.iteration < self.total

    def seconds(self) -> float:
        return self.earlier_s + time.perf_counter() - self.started

    def state(self, modules: Mapping, optimizer, schedule, **extra) -> dict:
        """What a checkpoint keeps: each module's state under its name, the optimizer's, the schedule's, the
        progress, and ``extra`` (tensors, numbers, strings, lists or dicts of those)."""
        import torch

        return {"iteration": self.iteration, "iterations": self.total,
                **{name: module.state_dict() for name, module in modules.items()},
                "optimizer": optimizer.state_dict(), "schedule": schedule.state_dict(),
                "losses": torch.tensor(self.losses, dtype=torch.float64), "seconds": self.seconds(), **extra}

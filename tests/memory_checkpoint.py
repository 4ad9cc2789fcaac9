"""A checkpoint kept in memory (the engine's is on storage, pipeline/checkpoints.py) that can stop a training
right after a save, the stand-in for a killed process in the trainings' resume tests."""

from __future__ import annotations


class Stopped(Exception):
    """The stand-in for a killed process: raised right after a checkpoint is saved."""


class MemoryCheckpoint:
    def __init__(self, stop_after: int | None = None):
        self.state, self.saves, self.stop_after = None, 0, stop_after

    def load(self):
        return self.state

    def save(self, state):
        self.state, self.saves = state, self.saves + 1
        if self.saves == self.stop_after:
            raise Stopped

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


def stopped_and_continued(train, stop_after: int):
    """``train(checkpoint)`` run whole, then stopped right after its ``stop_after``-th checkpoint and run again from
    it. -> (the whole run's result, the continued run's, the checkpoint as the stop left it: state and saves)"""
    import pytest

    whole = train(MemoryCheckpoint())
    checkpoint = MemoryCheckpoint(stop_after=stop_after)
    with pytest.raises(Stopped):
        train(checkpoint)
    at_stop = dict(checkpoint.state)
    checkpoint.stop_after = None
    resumed = train(checkpoint)
    return whole, resumed, at_stop, checkpoint.saves

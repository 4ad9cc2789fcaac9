"""Worker side: thread pools of a per-dataset task."""

from __future__ import annotations

import os

import cv2
import torch

from mocapflow.pipeline.execute import every_core


def test_a_per_dataset_task_gets_every_core_and_the_pools_are_restored_after():
    threads = torch.get_num_threads(), cv2.getNumThreads()
    try:
        torch.set_num_threads(1)
        cv2.setNumThreads(1)  # a worker process's share
        with every_core():
            assert torch.get_num_threads() == cv2.getNumThreads() == os.cpu_count()
        assert torch.get_num_threads() == cv2.getNumThreads() == 1
    finally:
        torch.set_num_threads(threads[0])
        cv2.setNumThreads(threads[1])

"""Fixtures of the policy tests: tiny LeRobot datasets in the mosaic format (see ``tests.helpers.policy``)."""

import os

os.environ.setdefault("HF_HUB_OFFLINE", "1")
os.environ.setdefault("WANDB_MODE", "disabled")

import torch

torch.set_num_threads(1)  # the CI machine is shared: one thread avoids OpenMP oversubscription stalls
import pytest

from tests.helpers.policy import write_dataset


@pytest.fixture(scope="session")
def door_datasets(tmp_path_factory):
    """(agent_root, demo_root): Panda-like and Sawyer-like datasets of door variations 0-3, 2 episodes each."""
    base = tmp_path_factory.mktemp("datasets")
    agent = write_dataset(base / "door_panda", "mosaic/door_panda", [0, 1, 2, 3])
    demo = write_dataset(base / "door_sawyer", "mosaic/door_sawyer", [0, 1, 2, 3])
    return agent, demo

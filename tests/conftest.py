"""Shared test set-up: headless rendering, no network, and one cached environment per (task, robot)."""

from __future__ import annotations

import os

os.environ.setdefault("MUJOCO_GL", "egl")
os.environ.setdefault("HF_HUB_OFFLINE", "1")
os.environ.setdefault("WANDB_MODE", "disabled")

import pytest  # noqa: E402
from filelock import FileLock  # noqa: E402

from mosaic_data.tasks import make_task_env  # noqa: E402
from tests.helpers.xdist_run import run_folder  # noqa: E402


@pytest.fixture(scope="session")
def task_env_cache():
    """Building a scene takes seconds; tests share one env per (task, robot) and switch variations on it."""
    cache = {}

    def get(task: str, robot: str, variation: int = 0):
        key = (task, robot)
        if key not in cache:
            cache[key] = make_task_env(task, variation, robot)
        env = cache[key]
        env.set_variation(variation)
        return env

    yield get
    for env in cache.values():
        env.close()


@pytest.fixture(scope="module")
def one_ray_session_at_a_time(tmp_path_factory):
    """Held by every test module that starts Ray, for the whole module. A Ray session is a dozen processes (GCS,
    raylets, dashboard and runtime-env agents, workers): two at once, one per xdist worker, brought a 2-core machine to
    a load average of 80."""
    with FileLock(run_folder(tmp_path_factory) / "ray_session.lock"):
        yield

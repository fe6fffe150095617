"""Fixtures of the collection tests: one real, tiny collection (door, every variation, both robots, 1 episode each),
the ``mosaic-data`` command in-process and the image size the collection used."""

from __future__ import annotations

import os
import shutil

os.environ.setdefault("MUJOCO_GL", "egl")
os.environ["HF_HUB_OFFLINE"] = "1"
os.environ["WANDB_MODE"] = "disabled"

import pytest  # noqa: E402
from filelock import FileLock  # noqa: E402

from tests.helpers.collection import HEIGHT, TEST_IMAGE_SIZE, WIDTH, run_cli  # noqa: E402
from tests.helpers.xdist_run import run_folder  # noqa: E402


@pytest.fixture(scope="session")
def door_output(tmp_path_factory):
    """Output dir holding mosaic/door_panda and mosaic/door_sawyer, collected with 2 workers. Collected once per
    pytest run: under pytest-xdist the first worker that asks collects it into the run's shared temporary folder
    (under a file lock) and the others read it. Tests copy it before changing anything."""
    shared = run_folder(tmp_path_factory)
    output, finished = shared / "door_datasets", shared / "door_datasets.finished"
    with FileLock(shared / "door_datasets.lock"):
        if not finished.exists():
            shutil.rmtree(output, ignore_errors=True)  # a worker that failed half-way leaves no marker
            status = run_cli(
                "collect", "--task", "door", "--robot", "both", "--episodes", "1", "--workers", "2",
                "--output-dir", str(output), "--image-size", TEST_IMAGE_SIZE, "--quiet",
            )
            assert status == 0
            finished.touch()
    return output


@pytest.fixture(scope="session")
def cli():
    """``mosaic-data`` in this process: ``cli("validate", path)`` returns the exit status."""
    return run_cli


@pytest.fixture(scope="session")
def image_size() -> tuple[int, int]:
    return HEIGHT, WIDTH

"""Shared fixture: one real, tiny collection (door, every variation, both robots, 1 episode each)."""

from __future__ import annotations

import os
import signal

os.environ.setdefault("MUJOCO_GL", "egl")
os.environ["HF_HUB_OFFLINE"] = "1"
os.environ["WANDB_MODE"] = "disabled"

import pytest  # noqa: E402

TEST_IMAGE_SIZE = "56x96"
"""Small images keep encoding cheap; the simulator, expert and horizon are the real ones."""


def ctrl_c_reaches_it() -> None:
    """``preexec_fn`` of a child process a test interrupts with SIGINT. A shell running the suite as a background job
    (``bash .ci/run &``, ``nohup ... &``) starts its commands with SIGINT ignored, which every child inherits; Python
    then never raises KeyboardInterrupt and the child goes on as if Ctrl-C had not been pressed. The child gets the
    default disposition back, as in a terminal."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def run_cli(*args: str) -> int:
    from mosaic_data.cli import main

    return main(list(args))


@pytest.fixture(scope="session")
def door_output(tmp_path_factory):
    """Output dir holding mosaic/door_panda and mosaic/door_sawyer, collected with 2 workers."""
    output = tmp_path_factory.mktemp("datasets")
    status = run_cli(
        "collect", "--task", "door", "--robot", "both", "--episodes", "1", "--workers", "2",
        "--output-dir", str(output), "--image-size", TEST_IMAGE_SIZE, "--quiet",
    )
    assert status == 0
    return output


@pytest.fixture(scope="session")
def cli():
    """``mosaic-data`` in this process: ``cli("validate", path)`` returns the exit status."""
    return run_cli


@pytest.fixture(scope="session")
def image_size() -> tuple[int, int]:
    height, width = (int(n) for n in TEST_IMAGE_SIZE.split("x"))
    return height, width

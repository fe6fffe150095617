"""`mosaic-data` as a user runs it: real subprocesses, exit codes, files written."""

from __future__ import annotations

import os
import subprocess
import sys

import numpy as np

from mosaic_data.tasks import TASKS, get_task_class


def run_cli(*args: str) -> subprocess.CompletedProcess:
    env = dict(os.environ, MUJOCO_GL=os.environ.get("MUJOCO_GL", "egl"))
    return subprocess.run([sys.executable, "-m", "mosaic_data.cli", *args], capture_output=True, text=True, env=env, timeout=600)


def test_tasks_lists_every_variation_with_unique_descriptions():
    result = run_cli("tasks")
    assert result.returncode == 0, result.stderr
    descriptions = [v.description for task in TASKS for v in get_task_class(task).variations]
    assert len(set(descriptions)) == len(descriptions), "variation descriptions must be unique across the suite"
    for description in descriptions:
        assert description in result.stdout
    assert f"{len(TASKS)} tasks, {len(descriptions)} variations" in result.stdout


def test_experts_writes_video_and_rerun(tmp_path):
    video = tmp_path / "door.mp4"
    result = run_cli("experts", "--task", "door", "--robot", "panda", "--episodes", "1", "--variations", "2", "--video", str(video))
    assert result.returncode == 0, result.stdout + result.stderr
    assert "100%" in result.stdout
    import imageio.v3 as iio

    frames = iio.imread(video, plugin="pyav")
    assert frames.shape[1:] == (100, 180, 3) and len(frames) > 10
    assert np.abs(frames[-1].astype(int) - frames[0].astype(int)).mean() > 1, "the door should have moved"

    recording = tmp_path / "door.rrd"
    result = run_cli("experts", "--task", "door", "--robot", "sawyer", "--episodes", "1", "--variations", "0", "--rerun", str(recording))
    assert result.returncode == 0, result.stdout + result.stderr
    from tests.helpers.recordings import rows_per_entity

    rows = rows_per_entity(recording)
    assert rows["/camera"] > 10
    assert rows["/camera"] == rows["/action/x"] == rows["/success"]
    assert {"/action/gripper", "/state/z", "/episode"} <= set(rows)

"""``mosaic-eval --executor ray`` on a real local Ray: the local executor's results, episode for episode, even after a
Ray worker is killed with ``kill -9`` in the middle of an episode."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from tests.helpers.processes import running_command_lines

from pipelines.evaluation.cli import main as mosaic_eval

pytestmark = pytest.mark.usefixtures("one_ray_session_at_a_time")

COMMON = ["--task", "door", "--variations", "0,3", "--episodes-per-variation", "2", "--max-steps", "8", "--seed", "5", "--quiet"]
TIMING_FIELDS = ("rollout_s", "act_s", "demo_s")


def _episodes(path: Path) -> list[dict]:
    return [{k: v for k, v in e.items() if k not in TIMING_FIELDS} for e in json.loads(path.read_text())["episodes"]]


def _running_episode_workers() -> list[int]:
    """Ray worker processes running an episode now (Ray titles a worker by the task it runs)."""
    return [pid for pid, line in running_command_lines().items() if line.startswith("ray::run_episode_task")]


def test_ray_results_equal_the_local_ones_after_a_killed_worker(tmp_path, tiny_checkpoint):
    local = tmp_path / "local" / "results.json"
    assert mosaic_eval([f"--policy.path={tiny_checkpoint}", *COMMON, "--workers", "1", "--output", str(local)]) == 0

    on_ray = tmp_path / "ray" / "results.json"
    command = [sys.executable, "-m", "pipelines.evaluation.cli", f"--policy.path={tiny_checkpoint}", *COMMON,
               "--executor", "ray", "--workers", "2", "--output", str(on_ray)]
    process = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 300
    while not _running_episode_workers():
        assert process.poll() is None, process.communicate()[1][-3000:]
        assert time.monotonic() < deadline, "no Ray worker ever ran an episode"
        time.sleep(0.1)
    os.kill(_running_episode_workers()[0], signal.SIGKILL)  # as the out-of-memory killer does
    stdout, stderr = process.communicate(timeout=600)
    assert process.returncode == 0, stderr[-3000:]
    assert "Traceback" not in stderr, stderr[-3000:]
    assert "on 2 worker(s)" in stdout

    assert _episodes(on_ray) == _episodes(local)
    assert json.loads(on_ray.read_text())["tables"] == json.loads(local.read_text())["tables"]
    assert not _running_episode_workers(), "Ray workers outlived mosaic-eval"


def test_ray_address_without_ray_executor_is_one_line(tmp_path, capsys):
    code = mosaic_eval(["--baseline", "expert", *COMMON, "--ray-address", "auto", "--output", str(tmp_path / "r.json")])
    assert code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == ["mosaic-eval: error: --ray-address needs --executor ray"]

"""``mosaic-data collect --executor ray`` on a real local Ray: the local executor's dataset, byte for byte in the
parquet columns and episode for episode in the sidecar, after a Ctrl-C of the driver and a ``kill -9`` of a Ray
worker in the middle of a shard."""

from __future__ import annotations

import glob
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pandas as pd
import pytest

from mosaic_data.collection.metadata import read_sidecar
from mosaic_data.collection.validate import validate_dataset

from tests.helpers.collection import TEST_IMAGE_SIZE, ctrl_c_reaches_it
from tests.helpers.processes import alive

pytestmark = pytest.mark.usefixtures("one_ray_session_at_a_time")

ARGS = ["collect", "--task", "door", "--robot", "panda", "--episodes", "1", "--executor", "ray", "--workers", "2",
        "--image-size", TEST_IMAGE_SIZE, "--quiet"]
"""The panda half of the shared ``door_output`` collection (every variation, 1 episode), on Ray."""


def _shards(staging: Path) -> tuple[list[str], list[Path]]:
    """(committed shard names, temporary folders of shards in flight)."""
    folder = staging / "shards"
    entries = list(folder.iterdir()) if folder.is_dir() else []
    return sorted(p.name for p in entries if ".tmp-" not in p.name), [p for p in entries if ".tmp-" in p.name]


def _start(output: Path) -> subprocess.Popen:
    command = [sys.executable, "-m", "mosaic_data.cli", *ARGS, "--output-dir", str(output)]
    return subprocess.Popen(command, env={**os.environ, "MUJOCO_GL": "egl"}, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            preexec_fn=ctrl_c_reaches_it)


def _wait_for(condition, process: subprocess.Popen, timeout_s: float = 300) -> None:
    deadline = time.monotonic() + timeout_s
    while not condition():
        assert process.poll() is None, f"collect ended early: {process.communicate()[1][-3000:]}"
        assert time.monotonic() < deadline, "timed out"
        time.sleep(0.1)


def _parquet(root: Path) -> pd.DataFrame:
    files = sorted(glob.glob(str(root / "data" / "**" / "*.parquet"), recursive=True))
    return pd.concat([pd.read_parquet(f) for f in files], ignore_index=True)


def test_ray_collection_survives_ctrl_c_and_a_killed_worker_and_equals_the_local_one(tmp_path, door_output):
    output = tmp_path / "out"
    staging = output / "mosaic" / ".door_panda.collecting"

    # 1. Ctrl-C on the driver once a shard is committed: exit 130, the workers stop, finished shards stay.
    process = _start(output)
    _wait_for(lambda: len(_shards(staging)[0]) >= 1, process)
    process.send_signal(signal.SIGINT)
    _, stderr = process.communicate(timeout=120)
    assert process.returncode == 130, stderr[-3000:]
    assert "run the same command again to resume" in stderr
    committed, in_flight = _shards(staging)
    time.sleep(3)  # a worker left running would commit (or keep writing) a shard in this time
    assert _shards(staging)[0] == committed and len(committed) < 4
    assert all(not alive(int(p.name.rsplit("-", 1)[1])) for p in in_flight), "Ray workers outlived Ctrl-C"

    # 2. Resume; kill -9 the Ray worker of a shard in flight (its pid names the shard's temporary folder).
    process = _start(output)

    def worker_in_flight() -> int | None:  # not a leftover of step 1, whose worker is dead
        pids = [int(p.name.rsplit("-", 1)[1]) for p in _shards(staging)[1]]
        return next((pid for pid in pids if alive(pid)), None)

    _wait_for(lambda: worker_in_flight() is not None, process)
    os.kill(worker_in_flight(), signal.SIGKILL)
    stdout, stderr = process.communicate(timeout=600)
    assert process.returncode == 0, stderr[-3000:]
    assert "Traceback" not in stderr, stderr[-3000:]
    assert f"collected {4 - len(committed)} episodes" in stdout, stdout  # the committed shards were not redone
    assert not staging.exists(), "the staging folder (and the killed worker's temporary shard) is gone"

    # 3. The same dataset as the local executor's (the shared fixture, 2 local worker processes).
    ray_root, local_root = output / "mosaic" / "door_panda", door_output / "mosaic" / "door_panda"
    _, problems = validate_dataset(ray_root)
    assert problems == []
    assert read_sidecar(ray_root)["episodes"] == read_sidecar(local_root)["episodes"]
    assert read_sidecar(ray_root)["sources"] == read_sidecar(local_root)["sources"]
    pd.testing.assert_frame_equal(_parquet(ray_root), _parquet(local_root), check_exact=True)


@pytest.mark.parametrize(
    "extra, message",
    [
        (["--ray-address", "127.0.0.1:9"], "--ray-address needs --executor ray"),
        (["--executor", "ray", "--ray-address", "127.0.0.1:9"], "cannot reach a Ray cluster at --ray-address 127.0.0.1:9"),
    ],
)
def test_ray_bad_input_is_one_line(tmp_path, extra, message):
    command = [sys.executable, "-m", "mosaic_data.cli", "collect", "--task", "door", "--robot", "panda", "--episodes", "1",
               "--output-dir", str(tmp_path), "--quiet", *extra]
    result = subprocess.run(command, capture_output=True, text=True, timeout=300)
    assert result.returncode == 2, result.stderr
    assert message in result.stderr and len(result.stderr.strip().splitlines()) == 1, result.stderr
    assert not (tmp_path / "mosaic" / "door_panda").exists()

"""``--ray-address`` against a real two-node Ray cluster on this machine (``ray start --head`` plus a worker node):
collection runs there; and a node that cannot see ``--output-dir`` (its own mount namespace, with an empty tmpfs over
the folder) stops the run before any work with one line that names the fix."""

from __future__ import annotations

import os
import shutil
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest

from mosaic_data.collection.metadata import read_sidecar

from conftest import TEST_IMAGE_SIZE

RAY = str(Path(sys.executable).with_name("ray"))


def _free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


def _nodes(address: str) -> int:
    import ray

    ray.init(address=address, logging_level="ERROR", log_to_driver=False)
    try:
        return sum(1 for node in ray.nodes() if node["Alive"])
    finally:
        ray.shutdown()


@pytest.fixture(scope="module")
def cluster(tmp_path_factory):
    """(address, hidden folder): a head node and a worker node of 1 CPU each; the worker node's processes see an
    empty tmpfs at ``hidden`` instead of the folder the driver sees."""
    if os.geteuid() != 0 or shutil.which("unshare") is None:
        pytest.skip("needs root and unshare to give a Ray node its own mount namespace")
    hidden = tmp_path_factory.mktemp("hidden")
    port = _free_port()
    address = f"127.0.0.1:{port}"
    env = {**os.environ, "RAY_AUTH_MODE": "disabled", "RAY_USAGE_STATS_ENABLED": "0"}
    common = ["--num-cpus=1", "--disable-usage-stats", "--block"]
    head = subprocess.Popen([RAY, "start", "--head", f"--port={port}", "--include-dashboard=false", *common], env=env,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    worker = None
    try:
        deadline = time.monotonic() + 120
        while True:  # the head answers
            try:
                socket.create_connection(("127.0.0.1", port), timeout=1).close()
                break
            except OSError:
                assert time.monotonic() < deadline and head.poll() is None, "the Ray head did not start"
                time.sleep(0.5)
        node = f"mount -t tmpfs none {hidden} && exec {RAY} start --address={address} {' '.join(common)}"
        worker = subprocess.Popen(["unshare", "--mount", "--propagation", "private", "bash", "-c", node], env=env,
                                  stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
        while _nodes(address) < 2:
            assert time.monotonic() < deadline and worker.poll() is None, "the Ray worker node did not join"
            time.sleep(1)
        yield address, hidden
    finally:
        for process in (worker, head):
            if process is not None and process.poll() is None:
                os.killpg(process.pid, signal.SIGTERM)  # `ray start --block` stops its node's processes
                try:
                    process.wait(timeout=60)
                except subprocess.TimeoutExpired:
                    os.killpg(process.pid, signal.SIGKILL)


def _collect(output: Path, address: str) -> subprocess.CompletedProcess:
    command = [sys.executable, "-m", "mosaic_data.cli", "collect", "--task", "door", "--robot", "panda", "--variations",
               "0,1", "--episodes", "1", "--executor", "ray", "--ray-address", address, "--image-size", TEST_IMAGE_SIZE,
               "--output-dir", str(output), "--quiet"]
    return subprocess.run(command, capture_output=True, text=True, timeout=600, env={**os.environ, "RAY_AUTH_MODE": "disabled"})


def test_collect_on_a_two_node_cluster_equals_the_local_collection(cluster, tmp_path, door_output):
    address, _ = cluster
    result = _collect(tmp_path, address)
    assert result.returncode == 0, result.stderr[-3000:]
    assert "with 2 worker(s)" in result.stdout, result.stdout  # one per cluster CPU
    records = read_sidecar(tmp_path / "mosaic" / "door_panda")["episodes"]
    local = read_sidecar(door_output / "mosaic" / "door_panda")["episodes"]
    assert [r | {"episode_index": 0} for r in records] == [r | {"episode_index": 0} for r in local if r["variation"] in (0, 1)]


def test_a_node_that_cannot_see_the_output_dir_stops_the_run_with_one_line(cluster):
    address, hidden = cluster
    result = _collect(hidden / "out", address)
    assert result.returncode == 2, result.stderr[-3000:]
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and "cannot see" in lines[0] and "every node mounts at the same path" in lines[0], lines
    assert not (hidden / "out" / "mosaic" / "door_panda").exists()

"""``--ray-address`` against a real two-node Ray cluster on this machine (``ray start --head`` plus a worker node):
collection runs there; and a node that cannot see ``--output-dir`` (its own mount namespace, with an empty tmpfs over
the folder) stops the run before any work with one line that names the fix; losing that node in the middle of a shard
costs nothing but the time to redo the shard."""

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

from tests.helpers.collection import TEST_IMAGE_SIZE

pytestmark = pytest.mark.usefixtures("one_ray_session_at_a_time")

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
def cluster(tmp_path_factory, one_ray_session_at_a_time):
    """(address, hidden folder, worker node process): a head node and a worker node of 1 CPU each; the worker node's processes see an
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
        yield address, hidden, worker
    finally:
        current = Path("/tmp/ray/ray_current_cluster")  # what `ray.init()` would join: not ours once we are gone
        if current.is_file() and current.read_text().strip().endswith(f":{port}"):
            current.unlink()
        for process in (worker, head):
            if process is not None and process.poll() is None:
                # every process of a node (raylet, GCS, workers) is in its `ray start`'s process group; SIGKILL
                # skips the graceful stop of SIGTERM, which waits on each of them in turn
                os.killpg(process.pid, signal.SIGKILL)
                process.wait()


def _collect(output: Path, address: str, variations: str) -> subprocess.Popen:
    command = [sys.executable, "-m", "mosaic_data.cli", "collect", "--task", "door", "--robot", "panda", "--variations",
               variations, "--episodes", "1", "--executor", "ray", "--ray-address", address, "--image-size", TEST_IMAGE_SIZE,
               "--output-dir", str(output), "--quiet"]
    return subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env={**os.environ, "RAY_AUTH_MODE": "disabled"})


def test_a_node_that_cannot_see_the_output_dir_stops_the_run_with_one_line(cluster):
    address, hidden, _ = cluster
    process = _collect(hidden / "out", address, "0")
    _, stderr = process.communicate(timeout=600)
    assert process.returncode == 2, stderr[-3000:]
    lines = stderr.strip().splitlines()
    assert len(lines) == 1 and "cannot see" in lines[0] and "every node mounts at the same path" in lines[0], lines
    assert not (hidden / "out" / "mosaic" / "door_panda").exists()


def _on_the_worker_node(pid: int) -> bool:
    """Whether ``pid`` runs in the worker node's mount namespace (not ours)."""
    try:
        return os.readlink(f"/proc/{pid}/ns/mnt") != os.readlink("/proc/self/ns/mnt")
    except OSError:
        return False


def test_collect_survives_losing_a_node_and_equals_the_local_collection(cluster, tmp_path, door_output):
    """Both nodes collect (one worker per cluster CPU); the worker node is killed (every process of it, SIGKILL)
    while it writes a shard; Ray runs that shard again on the head, and the dataset is the local executor's."""
    address, _, worker_node = cluster
    process = _collect(tmp_path, address, "0,1,2,3")
    shards = tmp_path / "mosaic" / ".door_panda.collecting" / "shards"
    deadline = time.monotonic() + 300
    while not any(_on_the_worker_node(int(p.name.rsplit("-", 1)[1])) for p in (shards.glob("*.tmp-*") if shards.is_dir() else [])):
        assert process.poll() is None, process.communicate()[1][-3000:]
        assert time.monotonic() < deadline, "the worker node never wrote a shard"
        time.sleep(0.1)
    os.killpg(worker_node.pid, signal.SIGKILL)  # the node is lost: its raylet, object store and workers
    stdout, stderr = process.communicate(timeout=600)
    assert process.returncode == 0, stderr[-3000:]
    assert "with 2 worker(s)" in stdout, stdout
    records = read_sidecar(tmp_path / "mosaic" / "door_panda")["episodes"]
    assert records == read_sidecar(door_output / "mosaic" / "door_panda")["episodes"]


def test_without_ray_address_a_command_starts_its_own_ray_even_beside_a_cluster(cluster, tmp_path):
    """``ray start`` left a cluster on this machine (``ray.init()`` would join it, and refuse our CPU count): without
    ``--ray-address`` mosaic-eval still starts a Ray of its own, as documented."""
    command = [sys.executable, "-m", "pipelines.evaluation.cli", "--baseline", "expert", "--task", "door", "--variations",
               "0", "--episodes-per-variation", "1", "--max-steps", "3", "--image-size", TEST_IMAGE_SIZE, "--executor", "ray",
               "--output", str(tmp_path / "results.json"), "--quiet"]
    result = subprocess.run(command, capture_output=True, text=True, timeout=600, env={**os.environ, "RAY_AUTH_MODE": "disabled"})
    assert result.returncode == 0, result.stderr[-3000:]
    assert (tmp_path / "results.json").is_file()

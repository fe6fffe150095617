"""A real collect process killed with SIGKILL mid-run, then resumed: nothing lost, duplicated or corrupt."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

from mosaic_data.collection.metadata import read_sidecar
from mosaic_data.collection.plan import episode_seed
from mosaic_data.collection.validate import validate_dataset

ARGS = ["collect", "--task", "door", "--robot", "panda", "--variations", "2,3", "--episodes", "1", "--seed", "5",
        "--workers", "1", "--image-size", "56x96", "--quiet"]


def _committed_shards(staging: Path) -> list[str]:
    shards = staging / "shards"
    return sorted(p.name for p in shards.iterdir() if ".tmp-" not in p.name) if shards.is_dir() else []


def test_sigkill_then_resume(tmp_path, door_output, cli, capsys):
    output = tmp_path / "out"
    staging = output / "mosaic" / ".door_panda.collecting"
    command = [sys.executable, "-m", "mosaic_data.cli", *ARGS, "--output-dir", str(output)]
    process = subprocess.Popen(command, env={**os.environ, "MUJOCO_GL": "egl"}, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    deadline = time.monotonic() + 240
    while not _committed_shards(staging) and time.monotonic() < deadline and process.poll() is None:
        time.sleep(0.2)
    assert process.poll() is None, process.stderr.read().decode()[-2000:]
    assert _committed_shards(staging) == ["v002_e00000-00001"]
    process.send_signal(signal.SIGKILL)
    process.wait()
    time.sleep(3)  # an orphaned worker would commit its shard in this time; it must be dead
    assert _committed_shards(staging) == ["v002_e00000-00001"]
    assert not (output / "mosaic" / "door_panda").exists()

    assert cli(*ARGS, "--output-dir", str(output)) == 0
    assert "collected 1 episodes" in capsys.readouterr().out  # the committed shard was not redone
    root = output / "mosaic" / "door_panda"
    assert not staging.exists()
    _, problems = validate_dataset(root)
    assert problems == []
    records = read_sidecar(root)["episodes"]
    assert [(r["episode_index"], r["variation"]) for r in records] == [(0, 2), (1, 3)]
    for record in records:
        assert record["seed"] == episode_seed(5, record["variation"], 0, record["attempts"] - 1)

    # The resumed dataset merges with the shared one into a valid multi-source dataset.
    assert cli("merge", str(door_output / "mosaic" / "door_panda"), str(root), "--repo-id", "mosaic/door_more_panda",
               "--output-dir", str(output)) == 0
    merged = output / "mosaic" / "door_more_panda"
    summary, problems = validate_dataset(merged)
    assert problems == [] and summary.startswith("6 episodes")

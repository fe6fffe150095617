"""Bad input: one error line, exit status 2, and nothing written."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest
from tests.helpers.cli_errors import one_line_error



@pytest.mark.parametrize(
    ("extra", "words"),
    [
        (["--task", "no_such_task"], ["unknown task", "door"]),
        (["--task", "doorr"], ["unknown task 'doorr'", "did you mean 'door'?"]),
        (["--task", "door", "--image-size", "10000x10000"], ["--image-size", "at most 8192x8192"]),
        (["--task", "door", "--executor", "ray", "--ray-address", " "], ["--ray-address is empty"]),
        (["--task", "door", "--variations", "0,9"], ["variation 9", "0..3"]),
        (["--task", "door", "--variations", "1,1"], ["--variations", "1 repeated"]),
        (["--task", "door", "--episodes", "0"], ["--episodes"]),
        (["--task", "all", "--variations", "0"], ["--task all"]),
    ],
)
def test_bad_options_write_nothing(tmp_path, cli, capsys, extra, words):
    output = tmp_path / "out"
    assert cli("collect", *extra, "--output-dir", str(output)) == 2
    one_line_error(capsys, *words)
    assert not output.exists()


def test_unwritable_output_dir(tmp_path, cli, capsys):
    blocker = tmp_path / "a_file"
    blocker.write_text("not a folder")
    assert cli("collect", "--task", "door", "--output-dir", str(blocker / "datasets")) == 2
    one_line_error(capsys, "not a writable folder")


def test_merge_into_a_folder_under_a_file_is_refused_first(tmp_path, cli, capsys):
    """Before the merge reads its sources (which name the fix for themselves), not at the end of its work."""
    blocker = tmp_path / "a_file"
    blocker.write_text("not a folder")
    sources = [str(tmp_path / "door_panda"), str(tmp_path / "drawer_panda")]
    assert cli("merge", *sources, "--repo-id", "mosaic/both_panda", "--output-dir", str(blocker / "datasets")) == 2
    one_line_error(capsys, "cannot write datasets under", str(blocker), "not a writable folder", "--output-dir")
    assert cli("merge", *sources, "--repo-id", "mosaic/both_panda", "--output-dir", str(blocker)) == 2
    one_line_error(capsys, "it is a file, not a folder", "--output-dir")
    assert sorted(tmp_path.iterdir()) == [blocker]


def test_lerobot_home_under_a_file_is_one_line(tmp_path):
    """Without --output-dir the datasets go to HF_LEROBOT_HOME; the error then says to set it. A fresh interpreter:
    LeRobot reads the variable once, when it is imported."""
    blocker = tmp_path / "a_file"
    blocker.write_text("not a folder")
    env = {**os.environ, "HF_LEROBOT_HOME": str(blocker / "lerobot"), "HF_HUB_OFFLINE": "1", "WANDB_MODE": "disabled"}
    for command in (["collect", "--task", "door"], ["merge", "a", "b", "--repo-id", "mosaic/both_panda"]):
        result = subprocess.run(
            [sys.executable, "-m", "mosaic_data.cli", *command], env=env, capture_output=True, text=True, timeout=300
        )
        error = result.stderr.strip()
        assert result.returncode == 2 and error.startswith("mosaic-data: error:") and "\n" not in error, error
        assert str(blocker) in error and "HF_LEROBOT_HOME" in error, error
    assert sorted(tmp_path.iterdir()) == [blocker]


def test_existing_dataset_of_another_schema_is_left_alone(tmp_path, cli, capsys):
    root = tmp_path / "mosaic" / "door_panda"
    (root / "meta").mkdir(parents=True)
    info = {"fps": 20, "features": {"observation.image": {"dtype": "video", "shape": [96, 96, 3]}}}
    (root / "meta" / "info.json").write_text(json.dumps(info))
    before = sorted(p.relative_to(tmp_path) for p in tmp_path.rglob("*"))
    assert cli("collect", "--task", "door", "--robot", "panda", "--output-dir", str(tmp_path)) == 2
    one_line_error(capsys, "another schema", "--overwrite")
    assert sorted(p.relative_to(tmp_path) for p in tmp_path.rglob("*")) == before


def test_bad_dataset_argument(tmp_path, cli, capsys):
    assert cli("validate", str(tmp_path / "nothing_here")) == 2
    one_line_error(capsys, "no LeRobot dataset")

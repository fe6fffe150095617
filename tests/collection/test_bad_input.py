"""Bad input: one error line, exit status 2, and nothing written."""

from __future__ import annotations

import json

import pytest
from cli_errors import one_line_error



@pytest.mark.parametrize(
    ("extra", "words"),
    [
        (["--task", "no_such_task"], ["unknown task", "door"]),
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

"""The README's scripts: `source scripts/setup.sh` (the way into the environment) must leave the user's shell as it
was, and the longest-first file order of `scripts/test.sh` must name files the suite has."""

from __future__ import annotations

import subprocess
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def test_sourcing_setup_keeps_the_callers_shell_options_and_folder(tmp_path):
    script = f"source {REPO / 'scripts' / 'setup.sh'} >/dev/null; false; echo alive; pwd; echo $MUJOCO_GL; echo $-"
    result = subprocess.run(["bash", "-c", script], cwd=tmp_path, capture_output=True, text=True, timeout=600)
    lines = result.stdout.split()
    assert lines[:2] == ["alive", str(tmp_path)], result.stdout + result.stderr  # no `set -e`, no `cd` left behind
    assert lines[2] == "egl" and "u" not in lines[3]


def test_the_longest_files_that_go_first_are_files_of_the_suite():
    from tests.helpers.xdist_run import LONGEST_FILES

    assert len(set(LONGEST_FILES)) == len(LONGEST_FILES)
    assert [path for path in LONGEST_FILES if not (REPO / path).is_file()] == []

"""`source scripts/setup.sh` (the README's way into the environment) must leave the user's shell as it was."""

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

"""What the pytest-xdist workers of one run share: the order files are handed out in, and a temporary folder for the
data and locks they share."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

LONGEST_FILES = (
    "tests/collection/test_data_safety.py",
    "tests/experiments/test_smoke_recipes.py",
    "tests/collection/test_ray_executor.py",
    "tests/policy/test_all_policies.py",
    "tests/test_tasks.py",
    "tests/evaluation/test_eval_hardening.py",
    "tests/collection/test_collect.py",
    "tests/collection/test_ray_cluster.py",
    "tests/test_quiet_startup.py",
    "tests/evaluation/test_same_numbers.py",
    "tests/evaluation/test_mosaic_eval.py",
    "tests/evaluation/test_ray_eval.py",
)
"""The suite's longest test files (a minute or more of one worker each), longest first, with the three that start
Ray spread apart: two Ray sessions at once wait on each other (see ``one_ray_session_at_a_time``)."""


def run_folder(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The temporary folder of the whole pytest run: under pytest-xdist the parent of every worker's own folder,
    otherwise the run's own."""
    base = tmp_path_factory.getbasetemp()
    return base.parent if os.environ.get("PYTEST_XDIST_WORKER") else base

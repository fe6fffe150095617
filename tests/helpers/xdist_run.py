"""What the pytest-xdist workers of one run share: a temporary folder for the data and locks they share."""

from __future__ import annotations

import os
from pathlib import Path

import pytest


def run_folder(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The temporary folder of the whole pytest run: under pytest-xdist the parent of every worker's own folder,
    otherwise the run's own."""
    base = tmp_path_factory.getbasetemp()
    return base.parent if os.environ.get("PYTEST_XDIST_WORKER") else base

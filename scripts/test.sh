#!/usr/bin/env bash
# The test command: set-up (if needed), then the fast test suite on the real simulator, headless.
# Extra arguments go to pytest, e.g. `bash scripts/test.sh -m slow` for the long expert success tables.
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."  # paths below are relative to the repository root
source scripts/setup.sh
# One pytest worker per core (at most 4), each test file on one worker so its module fixtures are built once; most
# tests wait on a subprocess (a collection, lerobot-train, mosaic-eval) for much of their time. The 15 slowest tests
# close the report.
python -m pytest -q --numprocesses=auto --maxprocesses=4 --dist=loadfile --durations=15 "$@"

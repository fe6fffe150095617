#!/usr/bin/env bash
# The test command: set-up (if needed), then the fast test suite on the real simulator, headless.
# Extra arguments go to pytest, e.g. `bash scripts/test.sh -m slow` for the long expert success tables.
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."  # paths below are relative to the repository root
source scripts/setup.sh
python -m pytest -q --durations=15 "$@"  # the 15 slowest tests close the report

#!/usr/bin/env bash
# The test command: set-up (if needed), then the fast test suite on the real simulator, headless.
# Extra arguments go to pytest, e.g. `bash scripts/test.sh -m slow` for the long expert success tables.
set -euo pipefail
source "$(dirname "${BASH_SOURCE[0]}")/setup.sh"
python -m pytest -q "$@"

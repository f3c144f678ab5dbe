#!/usr/bin/env bash
# Set up (idempotent) and run the whole test suite plus the linter.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
python3 -m ruff check prt_torch train export tests
python3 -m pytest -q -p no:randomly tests  # fixed order; scripts/test_matrix.sh shuffles

#!/usr/bin/env bash
# Install prt_torch with every extra (bake, train, export) and the dev tools into the current Python
# (torch pinned to the CPU build: installed first, so the extras resolve to it).
set -euo pipefail
cd "$(dirname "$0")/.."
export PIP_ROOT_USER_ACTION=ignore PIP_DISABLE_PIP_VERSION_CHECK=1
python3 -m pip install -q "torch==2.13.0"
python3 -m pip install -q -e ".[all,dev]" 2>&1 | grep -vE "^\s*$|BuildBackendWarning|!!|\*\*\*|Please be careful|name as your package|with strategy" || true

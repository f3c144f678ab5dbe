#!/usr/bin/env bash
# Install prt_torch and its dependencies into the current Python (torch pinned to the CPU build).
set -euo pipefail
cd "$(dirname "$0")/.."
export PIP_ROOT_USER_ACTION=ignore PIP_DISABLE_PIP_VERSION_CHECK=1
python3 -m pip install -q "torch==2.13.0"
python3 -m pip install -q -e ".[dev]" 2>&1 | grep -vE "^\s*$|BuildBackendWarning|!!|\*\*\*|Please be careful|name as your package|with strategy" || true

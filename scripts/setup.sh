#!/usr/bin/env bash
# Install prt_torch with every extra (bake, train, export) and the dev tools into the current Python
# (torch pinned to the CPU build: installed first, so the extras resolve to it).
set -euo pipefail
cd "$(dirname "$0")/.."
export PIP_ROOT_USER_ACTION=ignore PIP_DISABLE_PIP_VERSION_CHECK=1
python3 -m pip install -q "torch==2.13.0"
python3 -m pip install -q -e ".[all,dev]" 2>&1 | grep -vE "^\s*$|BuildBackendWarning|!!|\*\*\*|Please be careful|name as your package|with strategy" || true
# browser player (`prt web`): pinned three + onnxruntime-web from web/package-lock.json, and Debian's Chromium for
# `prt web --check` and tests/web; Xvfb for the interactive window's tests (tests/player/test_viewer.py) (as root;
# elsewhere those tests skip with one line saying so)
if command -v npm >/dev/null; then (cd web && npm ci --no-audit --no-fund --loglevel=error); else echo "setup: npm missing: prt web needs it"; fi
if ! command -v chromium >/dev/null && [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null; then
    (apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium >/dev/null) \
        || echo "setup: could not install chromium: tests/web will skip"
fi
if ! command -v Xvfb >/dev/null && [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null; then
    (apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq xvfb >/dev/null) \
        || echo "setup: could not install xvfb: tests/player/test_viewer.py's window tests will skip"
fi

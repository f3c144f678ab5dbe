#!/usr/bin/env bash
# Set up (idempotent) and run the main job end to end on the built-in character: runs/demo/
# (dataset, models, ONNX graphs, heldout.mp4, comparison.png, demo_metrics.json).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
prt demo "$@"

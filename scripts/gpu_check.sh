#!/usr/bin/env bash
# GPU check of the run-time path: onnxruntime's CUDA execution provider vs the CPU's default (compiled) path,
# `prt bench play --device cuda` for crowds of 1, 8, 32, 128, and the CPU compiled path and the scene on the device
# machine's 16 cores (`prt bench play`, `prt bench scene --characters 1/4/8`). Prints the figures; ~3-5 minutes on a
# warm GPU.
#
# 1. HERE (no GPU needed), once: a player-only copy of an exported run (every file its export.json records, ~31 MB
#    for the demo at int8, fits the device tool's 64 MiB carry; no dataset, no model file) and, if the device image lacks it, the onnxruntime-gpu wheel
#    (the device machine has no network):
#        scripts/gpu_check.sh --prepare runs/demo runs/gpu_demo
#        pip download onnxruntime-gpu --no-deps -d .whl      # optional: /.whl/ is git-ignored; carry it
# 2. ON THE DEVICE (the `run` tool), e.g. carry ["runs/gpu_demo", ".whl"], timeout_s 500:
#        bash scripts/gpu_check.sh runs/gpu_demo
#    It installs .whl/onnxruntime_gpu*.whl when onnxruntime offers no CUDA provider, runs the CUDA parity tests
#    (tests/runtime; skipped cleanly without a GPU) and a CPU-vs-CUDA parity of the player on the run, then the
#    benchmark. Targets (issue 14): >= 1000 frames/s single character, >= 10000 character-frames/s at 128.
set -uo pipefail
cd "$(dirname "$0")/.."

if [ "${1:-}" = "--prepare" ]; then
    src="${2:?source run}"; dst="${3:?destination}"
    mkdir -p "$dst/rpo"
    files=$(python3 -c "import json, sys; print(' '.join(json.load(open(sys.argv[1]))['file_sha256']))" \
        "$src/export.json") || exit 1
    for f in export.json character.npz stages.json $files; do
        cp "$src/$f" "$dst/$f" || exit 1
    done
    du -sh "$dst"
    exit 0
fi

run="${1:-runs/gpu_demo}"
py=python3
echo "== device"; nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv,noheader 2>&1 | head -2
$py - <<'EOF'
import onnxruntime as ort
print("onnxruntime", ort.__version__, ort.get_available_providers())
EOF
if ! $py -c "import onnxruntime as o, sys; sys.exit('CUDAExecutionProvider' not in o.get_available_providers())"; then
    whl=$(ls .whl/onnxruntime_gpu*.whl 2>/dev/null | head -1)
    if [ -n "$whl" ]; then
        $py -m pip uninstall -y -q onnxruntime >/dev/null 2>&1
        $py -m pip install -q --no-deps "$whl" && echo "installed $whl"
    else
        echo "no CUDA provider and no .whl/onnxruntime_gpu*.whl: carry the wheel (see the header)"; exit 2
    fi
fi
$py -m pip install -q -e . --no-deps >/dev/null 2>&1 || true

echo "== CUDA parity tests"
$py -m pytest -q tests/runtime -p no:cacheprovider -k "cuda or devices" 2>&1 | tail -3

echo "== player parity on $run: CUDA (fused, split) vs the CPU's default path (compiled)"
$py - "$run" <<'EOF'
import sys, numpy as np
from prt_torch.player import Player
run = sys.argv[1]
cpu = Player(run, brdf="phong")
print("CPU graph:", cpu.graph)
for graph in ("fused", "split"):
    gpu = Player(run, brdf="phong", graph=graph, device="cuda")
    loc = cpu.crowd_locals(list(cpu.character.clips)[:4] * 2, frame=3, stagger=5)
    want, got = cpu.compute(loc)[1], gpu.compute(loc)[1]
    err = float(np.abs(got - want).max() / np.abs(want).max())
    print(f"{graph}: precision {cpu.bundle.precision}, max |cuda - cpu| / max |cpu| = {err:.2e}",
          "OK" if err < 2e-3 else "TOO LARGE")
    print("  providers:", gpu.bundle.graphs["fused"].session.get_providers())
EOF

echo "== prt bench play --device cuda"
$py -m prt_torch bench play "$run" --device cuda --crowd 1,8,32,128 --precisions "" --raytrace-frames 0 \
    --frames 200 --repeats 3 --json > /tmp/gpu_bench.json
$py - <<'EOF'
import json
d = json.load(open("/tmp/gpu_bench.json"))
print(f"single character: {d['fps']:.0f} frames/s ({d['frame_ms']:.3f} ms; per repeat {d['frame_ms_per_repeat']})")
for k, s in d["steps"].items():
    print(f"  {k:10s} {s['ms']:.3f} ms")
for n, r in d["crowd"].items():
    print(f"crowd {n:>4}: {r['character_fps']:.0f} character-frames/s ({r['call_ms']:.2f} ms per call)")
EOF

echo "== the CPU compiled path on this machine's cores: prt bench play, prt bench scene --characters K"
$py -m prt_torch bench play "$run" --precisions "" --raytrace-frames 0 --frames 200 --repeats 3 --json \
    > /tmp/cpu_bench.json && $py - <<'EOF'
import json
d = json.load(open("/tmp/cpu_bench.json"))
print(f"CPU {d['threads']} threads, path {d['path']}: {d['fps']:.0f} frames/s, roofline fraction "
      f"{d['roofline_fraction']:.2f}; batch {d['batch']}: {d['batched_character_fps']:.0f} character-frames/s")
EOF
for k in 1 4 8; do
    $py -m prt_torch bench scene "$run" --characters "$k" --frames 10 --json 2>/dev/null | tail -1
done


"""A tiny end-to-end run built once per test session through ``prt demo`` (bake -> fit -> export ->
play -> compare), shared by tests/export, tests/player and tests/test_demo.py.

The run lives under pytest's session base temp directory; a marker file makes the second fixture
that asks for it (another test directory's conftest) reuse it instead of building it again.
"""

from __future__ import annotations

import time
from pathlib import Path

import yaml

TINY_CONFIG = {
    "name": "tiny",
    "character": {"source": "builtin", "density": 0.1, "fps": 6, "train_clips": ["walk", "squat", "stretch"],
                  "heldout_clips": ["wave"], "random_poses": 0, "seed": 0},
    "bake": {"order": 4, "n_rays": 64, "frames_per_task": 8, "workers": 1, "seed": 0},
    "train": {"kinds": ["linear", "mlp"], "default_kind": "mlp", "alphas": [0.01, 1.0], "mlp_alphas": [0.1],
              "neurons": [4], "folds": 2, "cv_iter": 20, "max_iter": 60, "seed": 0},
}


def build_tiny_run(base: Path) -> Path:
    """Run ``prt demo`` on :data:`TINY_CONFIG` into ``base/tiny_run`` (once); returns the run dir."""
    from prt_torch.cli import main

    run_dir = base / "tiny_run"
    marker = base / "tiny_run.done"
    if marker.is_file():
        return run_dir
    cfg_path = base / "tiny.yaml"
    cfg_path.write_text(yaml.safe_dump({**TINY_CONFIG, "run_dir": str(run_dir)}))
    t0 = time.perf_counter()
    rc = main(["demo", "--config", str(cfg_path), "--frames", "4", "--size", "240x160", "--brdf", "phong"])
    assert rc == 0, "prt demo failed on the tiny config"
    marker.write_text(f"{time.perf_counter() - t0:.1f}\n")
    return run_dir


def copy_run(src: Path, dst: Path) -> Path:
    """A working copy of the run ``src`` at ``dst`` without its videos, images, report and compare folders."""
    import shutil

    shutil.copytree(src, dst, ignore=shutil.ignore_patterns("*.mp4", "*.png", "report", "compare"))
    return dst

"""A tiny seed-001 run shared by the s001 tests: ``prt bake`` (transfer matrices) + ``prt train`` (``train.s001``).

A session fixture (registered by tests/conftest.py like every ``tests/fixtures_*.py``): the built-in character at
density 0.05, 24 cpca-sampled poses, order-3 matrices with one bounce, 32 rays (a few seconds on two cores).
"""

from __future__ import annotations

from pathlib import Path

import pytest

CONFIG = """
name: s001_test
run_dir: {run}
character:
  source: builtin
  density: 0.05
  fps: 6.0
  train_clips: [stretch, squat]
  random_poses: 24
  random_mode: cpca
  random_cpca_clusters: 3
  heldout_clips: [wave]
  seed: 0
bake:
  order: 3
  n_rays: 32
  transfer_matrix: true
  matrix_order: 3
  matrix_bounces: 1
  frames_per_task: 8
  workers: 1
  seed: 0
train:
  kinds: [linear]
  alphas: [0.1]
  folds: 2
  s001:
    clusters_per_segment: 3
    n_basis: 6
    cpca_iters: 2
"""


@pytest.fixture(scope="session")
def s001_run(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    """``(config path, run directory)`` of the baked and trained tiny run."""
    from prt_torch.cli import main

    root = tmp_path_factory.mktemp("s001")
    run = root / "run"
    cfg = root / "s001.yaml"
    cfg.write_text(CONFIG.format(run=run))
    assert main(["bake", str(cfg)]) == 0
    assert main(["train", str(cfg)]) == 0
    return cfg, run

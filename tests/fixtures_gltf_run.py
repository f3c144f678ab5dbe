"""A tiny exported run of a glTF character with a material, for the player tests (``prt play`` on a glTF
character, not only on the built-in one).

A session fixture (registered by tests/conftest.py like every ``tests/fixtures_*.py``): the synthetic figure of
:func:`tests.rig.gltf_synth.write_figure` (134 vertices, 3 joints, base colour ``(0.9, 0.45, 0.25)``), clips
at 6 fps, 12 random poses, order 3, 32 rays, with what every ``prt play --renderer`` needs: transfer
matrices and ``train.s001`` (``s001`` / ``posespace``), diffuse transfer and ``train.transfer``
(``transfer``), the learned models and ``prt export`` (``onnx``, ``sg``, ``--ground``, ``--scene``).
"""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml

FIGURE_CONFIG = {
    "name": "figure",
    "character": {"source": "figure.glb", "fps": 6.0, "train_clips": ["bend", "lift"], "heldout_clips": ["twist"],
                  "random_poses": 12, "seed": 0},
    "bake": {"order": 3, "n_rays": 32, "frames_per_task": 8, "workers": 1, "seed": 0, "min_cluster_size": 4,
             "transfer": True, "transfer_order": 3, "transfer_matrix": True, "matrix_order": 3,
             "matrix_bounces": 0, "blockers": 8},
    "train": {"kinds": ["linear"], "alphas": [0.1], "folds": 2, "threads": 1,
              "s001": {"clusters_per_segment": 2, "n_basis": 4, "cpca_iters": 1},
              "transfer": {"kinds": ["linear"], "input_components": 4, "output_components": 6}},
}


@pytest.fixture(scope="session")
def gltf_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The exported run directory of :data:`FIGURE_CONFIG` (``figure.glb`` and ``figure.yaml`` beside it)."""
    from prt_torch.cli import main
    from tests.rig.gltf_synth import write_figure

    root = tmp_path_factory.mktemp("gltf_run")
    write_figure(root / "figure.glb")
    run = root / "run"
    cfg = root / "figure.yaml"
    cfg.write_text(yaml.safe_dump({**FIGURE_CONFIG, "run_dir": str(run)}))
    for argv in (["bake", str(cfg), "--no-progress"], ["train", str(cfg)], ["export", str(run)]):
        assert main(argv) == 0, argv
    return run

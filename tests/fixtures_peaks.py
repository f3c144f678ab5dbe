"""Session fixtures of a run with peak lights (issue 27): baked with ``bake.peaks``, trained with ``train.peaks``
(the learned peak blockers) and exported (``peaks.onnx``, ``blockers.npz``).

* ``peak_run``: the run directory (its ``dataset.zarr``, ``peak_blockers.npz``, ``peaks.onnx``, the ONNX graphs).
"""

from __future__ import annotations

from pathlib import Path

import pytest

#: the config of ``peak_run``: the built-in character at density 0.25 (~2.9k vertices), few frames, 4 recorded
#: discs of 1 degree per frame with 3 x 3 rays each (stable: the peak tests rely on its shape); learned SPHERES (the
#: tests read peak_blockers.npz as a sphere set; the capsules' fit is tested on its dataset in tests/fit)
PEAK_CONFIG = {
    "name": "peaks",
    "character": {"source": "builtin", "density": 0.25, "fps": 10.0, "train_clips": ["stretch", "squat"],
                  "random_poses": 24, "heldout_clips": ["wave"], "seed": 0},
    "bake": {"order": 3, "n_rays": 64, "frames_per_task": 8, "seed": 0, "below_horizon": "zero", "blockers": 24,
             "peaks": {"directions": 4, "angular_radius_deg": 1.0, "disc_side": 3}},
    "train": {"kinds": ["linear"], "alphas": [1.0], "folds": 2, "cv_iter": 10, "max_iter": 20,
              "peaks": {"steps": 60, "frames_per_step": 4, "vertices_per_step": 1024, "eval_frames": 6,
                        "blockers": "spheres"}},
}


@pytest.fixture(scope="session")
def peak_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A baked, trained (with the learned peak blockers) and exported run of :data:`PEAK_CONFIG`."""
    from prt_torch.bake.runner import bake
    from prt_torch.config import config_from_dict
    from prt_torch.export.run import export_run
    from prt_torch.fit.train import train_dataset

    run_dir = tmp_path_factory.mktemp("peak_run")
    cfg = config_from_dict({**PEAK_CONFIG, "run_dir": str(run_dir)})
    dataset = bake(cfg, workers=1, progress=False)
    train_dataset(dataset, run_dir, cfg.train)
    export_run(run_dir)
    return run_dir

"""Session fixtures of baked datasets (owned by the bake helper).

* ``small_dataset``: the built-in character baked small and fast, for the fit/eval/export tests.
"""

from __future__ import annotations

from pathlib import Path

import pytest

#: the config of ``small_dataset`` (stable: other tests rely on its shape)
SMALL_CONFIG = {
    "name": "small",
    "character": {"source": "builtin", "density": 0.25, "fps": 10.0, "train_clips": ["stretch"],
                  "random_poses": 60, "heldout_clips": ["wave"], "seed": 0},
    "bake": {"order": 4, "n_rays": 128, "frames_per_task": 8, "seed": 0, "below_horizon": "zero"},
}


@pytest.fixture(scope="session")
def small_dataset(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Path of a complete ``dataset.zarr`` (layout: docs/DESIGN.md) baked from the built-in character.

    Built-in humanoid at density 0.25 (~2.9k vertices, 21 joints, pose features A = 120), clips
    sampled at 10 fps; 128 rays per vertex, SH order 4 (C = 16), frames_per_task 8. Frames
    (F = 132): clip ``stretch`` (41 frames) + ``random`` (60 random poses) = split ``train``
    (101 frames); clip ``wave`` (31 frames) = split ``heldout``. No transfer. ``character.npz``
    lies next to the dataset (``open_dataset(path).character()``). Bakes in-process in well under
    a minute; read it with ``prt_torch.bake.store.open_dataset``.
    """
    from prt_torch.bake.runner import bake
    from prt_torch.config import config_from_dict

    run_dir = tmp_path_factory.mktemp("small_bake")
    cfg = config_from_dict({**SMALL_CONFIG, "run_dir": str(run_dir)})
    return bake(cfg, workers=1, progress=False)

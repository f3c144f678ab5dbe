"""prt_torch.bake: the ground-truth bake (Embree rays -> local-frame SH visibility -> zarr dataset).

Public API (imported lazily so that ``prt_torch.rig.vertex_frames`` stays light for the player):
``bake(cfg, workers=None, scheduler=None, progress=True) -> Path``, ``run_bake``,
``open_dataset(path) -> BakedDataset``, ``vertex_frames``.
"""

from __future__ import annotations

from typing import Any

_LAZY = {
    "bake": "prt_torch.bake.runner",
    "run_bake": "prt_torch.bake.runner",
    "open_dataset": "prt_torch.bake.store",
    "BakedDataset": "prt_torch.bake.store",
    "vertex_frames": "prt_torch.rig.vertex_frames",
}

__all__ = sorted(_LAZY)


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        import importlib

        return getattr(importlib.import_module(_LAZY[name]), name)
    raise AttributeError(f"module 'prt_torch.bake' has no attribute {name!r}")

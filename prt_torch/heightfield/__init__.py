"""Dynamic height-field receivers and their SH visibility (seed 003 eq. 4-5, after Snyder & Nowrouzezahrai 2008).

* :mod:`~prt_torch.heightfield.surface`: the grid, its triangle mesh, normals and vertex frames; generators
  (:class:`Waves`, :class:`Terrain`).
* :mod:`~prt_torch.heightfield.horizon`: horizon angles per vertex and azimuthal wedge from a max pyramid.
* :mod:`~prt_torch.heightfield.wedges`: canonical visibility wedges tabulated as SH, rotated about ``+z``.
* :mod:`~prt_torch.heightfield.zrotation`: SH rotation into the vertex frames by z-rotations.
* :mod:`~prt_torch.heightfield.visibility`: :class:`HeightFieldVisibility` (the per-frame generator).
* :mod:`~prt_torch.heightfield.truth`: Embree truth through the bake's :func:`~prt_torch.bake.trace.trace_frame`.

``prt heightfield`` (``prt_torch.heightfield.command``) reports error, image PSNR and ms per frame vs Embree.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from prt_torch.heightfield.horizon import horizon_angles, max_pyramid, wedge_azimuths
    from prt_torch.heightfield.surface import (
        HeightFieldFrame,
        Terrain,
        Waves,
        grid_faces,
        grid_frames,
        grid_normals,
        make_frame,
        make_generator,
    )
    from prt_torch.heightfield.truth import truth_visibility
    from prt_torch.heightfield.visibility import HeightFieldVisibility
    from prt_torch.heightfield.wedges import WedgeTable, canonical_wedge
    from prt_torch.heightfield.zrotation import ZRotator, zyz_angles

#: exported name -> its submodule, imported on first access (module ``__getattr__``, PEP 562): importing one
#: submodule (a ``prt`` command or bench module, a stage hook) runs this package without importing torch
_LAZY: dict[str, str] = {
    "horizon_angles": "prt_torch.heightfield.horizon",
    "max_pyramid": "prt_torch.heightfield.horizon",
    "wedge_azimuths": "prt_torch.heightfield.horizon",
    "HeightFieldFrame": "prt_torch.heightfield.surface",
    "Terrain": "prt_torch.heightfield.surface",
    "Waves": "prt_torch.heightfield.surface",
    "grid_faces": "prt_torch.heightfield.surface",
    "grid_frames": "prt_torch.heightfield.surface",
    "grid_normals": "prt_torch.heightfield.surface",
    "make_frame": "prt_torch.heightfield.surface",
    "make_generator": "prt_torch.heightfield.surface",
    "truth_visibility": "prt_torch.heightfield.truth",
    "HeightFieldVisibility": "prt_torch.heightfield.visibility",
    "WedgeTable": "prt_torch.heightfield.wedges",
    "canonical_wedge": "prt_torch.heightfield.wedges",
    "ZRotator": "prt_torch.heightfield.zrotation",
    "zyz_angles": "prt_torch.heightfield.zrotation",
}

__all__ = [
    "HeightFieldFrame",
    "HeightFieldVisibility",
    "Terrain",
    "Waves",
    "WedgeTable",
    "ZRotator",
    "canonical_wedge",
    "grid_faces",
    "grid_frames",
    "grid_normals",
    "horizon_angles",
    "make_frame",
    "make_generator",
    "max_pyramid",
    "truth_visibility",
    "wedge_azimuths",
    "zyz_angles",
]


def __getattr__(name: str) -> Any:
    """The exports, imported on first access (``from prt_torch.heightfield import X`` works as before)."""
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted({*globals(), *_LAZY})

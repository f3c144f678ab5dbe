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

from typing import TYPE_CHECKING

from prt_torch.lazy import lazy_exports

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

#: submodule -> the names exported from it, imported on first access (:func:`prt_torch.lazy.lazy_exports`):
#: importing one submodule (a ``prt`` command or bench module, a stage hook) runs this package without torch
_EXPORTS: dict[str, tuple[str, ...]] = {
    "prt_torch.heightfield.horizon": ("horizon_angles", "max_pyramid", "wedge_azimuths"),
    "prt_torch.heightfield.surface": (
        "HeightFieldFrame", "Terrain", "Waves", "grid_faces", "grid_frames", "grid_normals", "make_frame",
        "make_generator",
    ),
    "prt_torch.heightfield.truth": ("truth_visibility",),
    "prt_torch.heightfield.visibility": ("HeightFieldVisibility",),
    "prt_torch.heightfield.wedges": ("WedgeTable", "canonical_wedge"),
    "prt_torch.heightfield.zrotation": ("ZRotator", "zyz_angles"),
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

lazy_exports(__name__, _EXPORTS)

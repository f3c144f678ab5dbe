"""Voxel cone-traced visibility of animated geometry (seed 004 sec. 5; Crassin et al. 2011).

Per frame: voxelise the posed mesh into a dense opacity grid (:mod:`prt_torch.vct.voxelize`), pre-filter it
into a mip pyramid packed in one 3D atlas (:mod:`prt_torch.vct.pyramid`), and trace cones from every shaded
vertex with ``grid_sample`` front-to-back opacity accumulation (:mod:`prt_torch.vct.trace`). The cones come
from the BRDF lobes (eq. 5-6 aperture, 7 sub-cones by circle packing, Fig. 4) and the detected light peaks
(:mod:`prt_torch.vct.cones`). Everything is torch: the device follows the input tensors.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from prt_torch.lazy import lazy_exports

if TYPE_CHECKING:
    from prt_torch.vct.cones import ConeSet, cone_aperture, cone_sharpness, pack_lobe_cones, peak_cones
    from prt_torch.vct.grid import VoxelGrid, fit_grid
    from prt_torch.vct.pyramid import OpacityPyramid, build_pyramid
    from prt_torch.vct.trace import TraceSettings, trace_cones
    from prt_torch.vct.visibility import ConeTracer
    from prt_torch.vct.voxelize import is_closed_mesh, voxelize

#: submodule -> the names exported from it, imported on first access (:func:`prt_torch.lazy.lazy_exports`):
#: importing one submodule (a ``prt`` command or bench module, a stage hook) runs this package without torch
_EXPORTS: dict[str, tuple[str, ...]] = {
    "prt_torch.vct.cones": ("ConeSet", "cone_aperture", "cone_sharpness", "pack_lobe_cones", "peak_cones"),
    "prt_torch.vct.grid": ("VoxelGrid", "fit_grid"),
    "prt_torch.vct.pyramid": ("OpacityPyramid", "build_pyramid"),
    "prt_torch.vct.trace": ("TraceSettings", "trace_cones"),
    "prt_torch.vct.visibility": ("ConeTracer",),
    "prt_torch.vct.voxelize": ("is_closed_mesh", "voxelize"),
}

__all__ = ["ConeSet", "ConeTracer", "OpacityPyramid", "TraceSettings", "VoxelGrid", "build_pyramid",
           "cone_aperture", "cone_sharpness", "fit_grid", "is_closed_mesh", "pack_lobe_cones", "peak_cones",
           "trace_cones", "voxelize"]

lazy_exports(__name__, _EXPORTS)

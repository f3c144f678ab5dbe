"""Voxel cone-traced visibility of animated geometry (seed 004 sec. 5; Crassin et al. 2011).

Per frame: voxelise the posed mesh into a dense opacity grid (:mod:`prt_torch.vct.voxelize`), pre-filter it
into a mip pyramid packed in one 3D atlas (:mod:`prt_torch.vct.pyramid`), and trace cones from every shaded
vertex with ``grid_sample`` front-to-back opacity accumulation (:mod:`prt_torch.vct.trace`). The cones come
from the BRDF lobes (eq. 5-6 aperture, 7 sub-cones by circle packing, Fig. 4) and the detected light peaks
(:mod:`prt_torch.vct.cones`). Everything is torch: the device follows the input tensors.
"""

from __future__ import annotations

import importlib
import sys
import types
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from prt_torch.vct.cones import ConeSet, cone_aperture, cone_sharpness, pack_lobe_cones, peak_cones
    from prt_torch.vct.grid import VoxelGrid, fit_grid
    from prt_torch.vct.pyramid import OpacityPyramid, build_pyramid
    from prt_torch.vct.trace import TraceSettings, trace_cones
    from prt_torch.vct.visibility import ConeTracer
    from prt_torch.vct.voxelize import is_closed_mesh, voxelize

#: exported name -> its submodule, imported on first access (module ``__getattr__``, PEP 562): importing one
#: submodule (a ``prt`` command or bench module, a stage hook) runs this package without importing torch
_LAZY: dict[str, str] = {
    "ConeSet": "prt_torch.vct.cones",
    "cone_aperture": "prt_torch.vct.cones",
    "cone_sharpness": "prt_torch.vct.cones",
    "pack_lobe_cones": "prt_torch.vct.cones",
    "peak_cones": "prt_torch.vct.cones",
    "VoxelGrid": "prt_torch.vct.grid",
    "fit_grid": "prt_torch.vct.grid",
    "OpacityPyramid": "prt_torch.vct.pyramid",
    "build_pyramid": "prt_torch.vct.pyramid",
    "TraceSettings": "prt_torch.vct.trace",
    "trace_cones": "prt_torch.vct.trace",
    "ConeTracer": "prt_torch.vct.visibility",
    "is_closed_mesh": "prt_torch.vct.voxelize",
    "voxelize": "prt_torch.vct.voxelize",
}

__all__ = ["ConeSet", "ConeTracer", "OpacityPyramid", "TraceSettings", "VoxelGrid", "build_pyramid",
           "cone_aperture", "cone_sharpness", "fit_grid", "is_closed_mesh", "pack_lobe_cones", "peak_cones",
           "trace_cones", "voxelize"]


def __getattr__(name: str) -> Any:
    """The exports, imported on first access (``from prt_torch.vct import X`` works as before)."""
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted({*globals(), *_LAZY})


class _Package(types.ModuleType):
    """This package, keeping an export whose name is also its submodule's (``voxelize``): importing the submodule
    binds the module on the package, and the export (the function of the same name) is kept instead, as the eager
    ``from prt_torch.vct.voxelize import voxelize`` did."""

    def __setattr__(self, name: str, value: Any) -> None:
        if isinstance(value, types.ModuleType) and _LAZY.get(name) == value.__name__:
            value = getattr(value, name)
        super().__setattr__(name, value)


sys.modules[__name__].__class__ = _Package

"""Real spherical harmonics: basis, quadrature, projection, rotation, products, zonal harmonics.

Only :mod:`prt_torch.sh.basis` is imported eagerly (numpy only); the other modules' public names are
re-exported lazily on first attribute access, so ``import prt_torch.sh`` stays torch- and scipy-free.
None of the modules imports torch at import time.
"""

from __future__ import annotations

import importlib
from typing import Any

from prt_torch.sh.basis import (
    band_of,
    check_directions,
    check_order,
    num_coeffs,
    order_from_coeffs,
    sh_basis,
    sh_index,
)

_LAZY = {
    "sphere_quadrature": "quadrature",
    "hemisphere_directions": "quadrature",
    "sphere_directions": "quadrature",
    "random_rotations": "quadrature",
    "rotations_about_z": "quadrature",
    "project": "project",
    "reconstruct": "project",
    "evaluate": "project",
    "sh_rotation": "rotation",
    "sh_rotation_blocks": "rotation",
    "gauss_product_rule": "quadrature",
    "gaunt_tensor": "product",
    "GauntTensor": "product",
    "product_matrix": "product",
    "sh_product": "product",
    "zh_to_sh": "zonal",
    "rotate_zh": "zonal",
    "lobes_to_sh": "zonal",
    "zh_band_scale": "zonal",
    "zh_from_axial": "zonal",
    "zh_to_axial": "zonal",
    "clamped_cosine_zh": "zonal",
    "hemisphere_zh": "zonal",
    "zh_project": "zonal",
    "irradiance_sh": "zonal",
    "fit_zh_lobes": "zhfit",
    "ZHLobes": "zhfit",
}

__all__ = [
    "band_of",
    "check_directions",
    "check_order",
    "num_coeffs",
    "order_from_coeffs",
    "sh_basis",
    "sh_index",
    *_LAZY,
]


def __getattr__(name: str) -> Any:
    mod = _LAZY.get(name)
    if mod is None:
        raise AttributeError(f"module 'prt_torch.sh' has no attribute {name!r}")
    return getattr(importlib.import_module(f"prt_torch.sh.{mod}"), name)

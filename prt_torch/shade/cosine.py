"""The cosine product matrix of seed 003 eq. 14: the foreshortening term as an SH product operator.

``C_ij = sum_k c_k Gamma_ijk`` with ``c_k = int max(N . s, 0) y_k(s) ds``. In a vertex's local frame
``N = +z`` and ``c`` is the clamped-cosine zonal harmonic, ``c_{l0} = A_l sqrt((2l+1)/(4 pi))`` (R&H 2001
``A_l = pi, 2pi/3, pi/4, 0, -pi/24, ...``), all ``m != 0`` zero. So ``l . (C v)`` is the (order-``n``
projected) irradiance integral ``int L V max(cos, 0)`` and ``albedo/pi * l . (C v)`` is Lambertian shading.
"""

from __future__ import annotations

import numpy as np

from prt_torch.sh.basis import check_directions, check_order
from prt_torch.sh.product import MAX_PRODUCT_ORDER, product_matrix
from prt_torch.sh.zonal import clamped_cosine_zh, zh_to_sh


def cosine_product_matrix(order: int, normal: np.ndarray | None = None) -> np.ndarray:
    """``C (C, C)`` float64 of eq. 14 for the unit ``normal`` (default local ``+z``); symmetric."""
    check_order(order, MAX_PRODUCT_ORDER)
    n = np.array([0.0, 0.0, 1.0]) if normal is None else np.asarray(normal, dtype=np.float64)
    check_directions(n, "normal")
    return product_matrix(zh_to_sh(clamped_cosine_zh(order), n))

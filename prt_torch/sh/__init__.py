"""Real spherical harmonics: basis, quadrature, projection, rotation, products, zonal harmonics."""

from prt_torch.sh.basis import (
    band_of,
    check_directions,
    check_order,
    num_coeffs,
    order_from_coeffs,
    sh_basis,
    sh_index,
)

__all__ = ["band_of", "check_directions", "check_order", "num_coeffs", "order_from_coeffs", "sh_basis", "sh_index"]

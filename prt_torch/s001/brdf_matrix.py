"""The SH BRDF matrix of seed 001 eq. 5 and its SVD factorisation ``B ~ H G^T`` (sec. 5).

For a BRDF with scalar shape ``s(wi, wo)`` (local frame, z = normal, :mod:`prt_torch.brdf.analytic`) and the
cosine-weighted ``f~(wi, wo) = s(wi, wo) max(wi.z, 0)``, the exit radiance toward ``wo`` under local incident
radiance ``l(wi) = sum_j l_j y_j(wi)`` is ``int f~(wi, wo) l(wi) dwi = sum_j P_j(wo) l_j`` with the light-side
projections ``P_j(wo) = int f~(wi, wo) y_j(wi) dwi`` (over the sphere; ``f~ = 0`` below the horizon). The
view side is expanded in SH too, by least squares over the upper hemisphere (the only domain of ``wo``, as
:func:`prt_torch.brdf.factor.project_factors` does)::

    P_j(wo) ~= sum_i y_i(wo) B_ij,      Gamma(wo) = y(wo)^T B l = y(wo)^T B T L      (eq. 5, V = y(wo))

``B (C, C)``: row index = view SH, column index = light SH. Both integrals use the hemisphere product rule of
:mod:`prt_torch.brdf.factor` (``tabulate``). :func:`factor` truncates the SVD: ``B ~ H G^T``, ``H = U_k
sqrt(S_k)`` (view map), ``G = V_k sqrt(S_k)`` (light map); the 4-term error is the Eckart-Young bound
``sqrt(sum_{b >= k} s_b^2)`` (Frobenius). The RGB tint is not in ``B`` (apply it at shading).
"""

from __future__ import annotations

import numpy as np

from prt_torch.brdf.factor import DEFAULT_N_PHI, DEFAULT_N_THETA, hemisphere_rule, tabulate
from prt_torch.errors import PrtError
from prt_torch.sh.basis import check_order, sh_basis
from prt_torch.shapes import check_shape

#: highest SH order of a BRDF matrix
MAX_BRDF_MATRIX_ORDER = 8


def brdf_matrix(brdf: object, order: int = 4, n_theta: int = DEFAULT_N_THETA, n_phi: int = DEFAULT_N_PHI
                ) -> np.ndarray:
    """``B (C, C)`` float64, ``C = order**2`` (rows: view SH, columns: light SH); see the module docstring."""
    check_order(order, MAX_BRDF_MATRIX_ORDER)
    if 2 * n_theta < 2 * order or n_phi < 2 * order:
        raise PrtError(f"hemisphere rule {n_theta} x {n_phi} is too coarse for order {order}")
    dirs, w = hemisphere_rule(n_theta, n_phi)
    F = tabulate(brdf, dirs, dirs)  # (Ni, No): f~(wi_i, wo_o)
    Y = sh_basis(dirs, order, check=False)  # (N, C), the same rule for wi and wo
    P = (Y * w[:, None]).T @ F  # (C_light, No): P_j(wo)
    sw = np.sqrt(w)
    B, *_ = np.linalg.lstsq(Y * sw[:, None], (P * sw[None, :]).T, rcond=None)  # (C_view, C_light)
    return B


def factor(B: np.ndarray, terms: int = 4) -> tuple[np.ndarray, np.ndarray]:
    """Truncated SVD ``B ~ H G^T``: ``H (C, terms)`` view map, ``G (C, terms)`` light map (float64)."""
    B = np.asarray(B, dtype=np.float64)
    check_shape(B, "C C", name="BRDF matrix")
    if B.shape[0] < 1:
        raise PrtError(f"BRDF matrix must be square (C, C), got {B.shape}")
    if not np.isfinite(B).all():
        raise PrtError("BRDF matrix contains NaN or Inf")
    if not isinstance(terms, int | np.integer) or isinstance(terms, bool) or not 1 <= terms <= B.shape[0]:
        raise PrtError(f"BRDF matrix terms must be an integer in 1..{B.shape[0]}, got {terms!r}")
    U, S, Vt = np.linalg.svd(B)
    r = np.sqrt(S[:terms])
    H = U[:, :terms] * r
    G = Vt[:terms].T * r
    sgn = np.where(G.sum(0) < 0, -1.0, 1.0)  # deterministic signs
    return H * sgn, G * sgn

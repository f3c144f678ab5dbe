"""Tabulation of the cosine-weighted BRDF and its Kautz-McCool SVD factorisation, projected to SH.

``f~(wi, wo) = s(wi, wo) max(wi.z, 0)`` (the scalar BRDF shape, see :mod:`prt_torch.brdf.analytic`) is
tabulated on a product quadrature rule of the upper hemisphere for both ``wi`` and ``wo``
(Gauss-Legendre in ``cos theta`` on ``[0, 1]`` x uniform azimuth; weights sum to ``2 pi``). Rows and
columns are scaled by the square roots of the quadrature weights, ``A = diag(sqrt(a)) F diag(sqrt(b))``,
so that the Frobenius norm of ``A`` is the L2 norm of ``f~`` over (hemisphere x hemisphere) and the SVD
truncation to ``k`` terms is the best rank-``k`` approximation in that norm (Kautz & McCool 1999):

    f~(wi, wo) ~= sum_b U_b(wi) W_b(wo),   rel_error = sqrt(sum_{b >= k} s_b^2 / sum_b s_b^2)

with ``U_b = sqrt(s_b) U[:, b] / sqrt(a)`` and ``W_b = sqrt(s_b) V[:, b] / sqrt(b)``.

SH (order ``n``):

* ``u_b = <U_b, y>`` over the **sphere** (``U_b = 0`` below the horizon), by the same quadrature;
* ``w_b``: least-squares fit of ``W_b`` over the **upper hemisphere** (the only domain of ``wo``),
  i.e. the orthogonal projection in ``L2(hemisphere)``, which avoids fitting an arbitrary extension
  below the horizon.

numpy only.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from prt_torch.errors import PrtError
from prt_torch.sh.basis import check_order, sh_basis
from prt_torch.shapes import check_shape

#: default tabulation resolution: Gauss-Legendre nodes in cos(theta) x azimuths (per direction set)
DEFAULT_N_THETA = 24
DEFAULT_N_PHI = 48
#: BRDF terms ``k`` of a factorisation, of an RPO and of the exported shading graphs by default (``prt export
#: --terms``)
DEFAULT_TERMS = 8


def hemisphere_rule(n_theta: int = DEFAULT_N_THETA, n_phi: int = DEFAULT_N_PHI) -> tuple[np.ndarray, np.ndarray]:
    """Product quadrature on the upper hemisphere: ``dirs (N, 3)``, ``weights (N,)`` summing to ``2 pi``.

    Gauss-Legendre in ``z = cos theta`` on ``(0, 1)`` (``n_theta`` nodes) x ``n_phi`` uniform azimuths;
    exact for polynomials in ``(x, y, z)`` of degree ``< min(2 n_theta, n_phi)`` restricted to ``z >= 0``.
    """
    if not (isinstance(n_theta, int) and isinstance(n_phi, int)) or n_theta < 1 or n_phi < 1:
        raise PrtError(f"hemisphere rule needs positive integer sizes, got n_theta={n_theta!r}, n_phi={n_phi!r}")
    x, wx = np.polynomial.legendre.leggauss(n_theta)
    z = (x + 1) / 2
    wz = wx / 2
    phi = (np.arange(n_phi) + 0.5) * (2 * math.pi / n_phi)
    r = np.sqrt(1 - z * z)
    dirs = np.stack([np.outer(r, np.cos(phi)), np.outer(r, np.sin(phi)), np.repeat(z[:, None], n_phi, 1)], -1)
    w = np.repeat(wz[:, None] * (2 * math.pi / n_phi), n_phi, 1)
    return dirs.reshape(-1, 3), w.reshape(-1)


def tabulate(brdf: object, wi: np.ndarray, wo: np.ndarray) -> np.ndarray:
    """Cosine-weighted BRDF shape ``F[i, j] = s(wi_i, wo_j) max(wi_i.z, 0)``, ``(Ni, No)`` float64.

    ``brdf`` needs a ``shape(wi (N,3), wo (N,3)) -> (N,)`` method (all BRDFs here have one).
    Evaluated in row blocks (vectorised over all pairs of a block).
    """
    if not hasattr(brdf, "shape") or not callable(brdf.shape):
        raise PrtError(f"tabulate needs a BRDF with a shape(wi, wo) method, got {type(brdf).__name__}")
    ni, no = len(wi), len(wo)
    out = np.empty((ni, no))
    block = max(1, (1 << 20) // max(no, 1))
    for s in range(0, ni, block):
        a = wi[s:s + block]
        pi = np.repeat(a, no, axis=0)
        po = np.tile(wo, (len(a), 1))
        out[s:s + block] = brdf.shape(pi, po).reshape(len(a), no) * np.maximum(a[:, 2:3], 0.0)
    if not np.isfinite(out).all():
        raise PrtError(f"BRDF {getattr(brdf, 'name', '?')} produced NaN or Inf values")
    return out


@dataclass
class BRDFFactors:
    """A ``k``-term separable approximation ``f~(wi, wo) ~= sum_b U_b(wi) W_b(wo)``.

    Attributes:
        light: ``(k, Ni)`` light factors ``U_b`` at ``dirs_in``.
        view: ``(k, No)`` view factors ``W_b`` at ``dirs_out``.
        dirs_in, weights_in: ``(Ni, 3)``, ``(Ni,)`` upper-hemisphere quadrature of ``wi``.
        dirs_out, weights_out: ``(No, 3)``, ``(No,)`` upper-hemisphere quadrature of ``wo``.
        singular_values: the ``k`` leading singular values of the weighted table (descending).
        rel_error: relative L2 error of the ``k``-term truncation.
    """

    light: np.ndarray
    view: np.ndarray
    dirs_in: np.ndarray
    weights_in: np.ndarray
    dirs_out: np.ndarray
    weights_out: np.ndarray
    singular_values: np.ndarray
    rel_error: float

    @property
    def k(self) -> int:
        """Number of terms."""
        return int(self.light.shape[0])


def _top_svd(A: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Leading ``k`` singular triplets, descending: randomized SVD (Halko et al., scikit-learn; 6 power
    iterations, 24 oversamples, fixed seed: singular values to ~1e-6 relative on BRDF tables) when ``k`` is small
    against the table, else LAPACK's full SVD."""
    if 4 * k < min(A.shape):
        from sklearn.utils.extmath import randomized_svd

        return randomized_svd(A, k, n_oversamples=24, n_iter=6, random_state=0)
    U, S, Vt = np.linalg.svd(A, full_matrices=False)
    return U[:, :k], S[:k], Vt[:k]


def factor_brdf(brdf: object, k: int = DEFAULT_TERMS, n_theta: int = DEFAULT_N_THETA, n_phi: int = DEFAULT_N_PHI,
                table: np.ndarray | None = None) -> BRDFFactors:
    """Kautz-McCool SVD factorisation of the cosine-weighted BRDF shape to ``k`` terms.

    Args:
        brdf: a BRDF (``shape(wi, wo)``); ignored when ``table`` is given.
        k: number of terms (1..Ni).
        n_theta, n_phi: hemisphere rule size for both ``wi`` and ``wo``.
        table: optional precomputed ``(N, N)`` :func:`tabulate` output on that rule.
    """
    if not isinstance(k, int) or isinstance(k, bool) or k < 1:
        raise PrtError(f"number of BRDF terms k must be a positive integer, got {k!r}")
    dirs, w = hemisphere_rule(n_theta, n_phi)
    if k > len(w):
        raise PrtError(f"k={k} exceeds the {len(w)} tabulated directions")
    F = tabulate(brdf, dirs, dirs) if table is None else np.asarray(table, dtype=np.float64)
    check_shape(F, (len(w), len(w)), name="BRDF table")
    sw = np.sqrt(w)
    A = sw[:, None] * F * sw[None, :]
    U, S, Vt = _top_svd(A, k)
    total = float(np.sum(A * A))  # ||A||_F^2 = sum of all squared singular values
    rel = math.sqrt(max(total - float(np.sum(S**2)), 0.0) / total) if total > 0 else 0.0
    r = np.sqrt(S[:k])
    light = (U[:, :k] * r).T / sw[None, :]
    view = (Vt[:k].T * r).T / sw[None, :]
    # deterministic signs: make each light factor integrate to a non-negative value
    sgn = np.where((light * w).sum(1) < 0, -1.0, 1.0)[:, None]
    return BRDFFactors(light * sgn, view * sgn, dirs, w, dirs, w, S, rel)


def project_factors(factors: BRDFFactors, order: int) -> tuple[np.ndarray, np.ndarray]:
    """SH coefficients of the factors: ``u (k, C)`` (sphere projection), ``w (k, C)`` (hemisphere LSQ)."""
    check_order(order)
    yi = sh_basis(factors.dirs_in, order, check=False)  # (Ni, C)
    u = (factors.light * factors.weights_in[None, :]) @ yi
    yo = sh_basis(factors.dirs_out, order, check=False)
    sw = np.sqrt(factors.weights_out)
    # weighted least squares over the hemisphere: min || sqrt(b) (Y w - W) ||
    coef, *_ = np.linalg.lstsq(yo * sw[:, None], (factors.view * sw[None, :]).T, rcond=None)
    return u, coef.T


def sh_factor_error(factors: BRDFFactors, u: np.ndarray, w: np.ndarray, table: np.ndarray) -> float:
    """Relative L2 error of ``sum_b (u_b . y(wi)) (w_b . y(wo))`` vs the table ``f~`` over
    (sphere of ``wi``) x (hemisphere of ``wo``); the lower ``wi`` hemisphere (where ``f~ = 0``) uses the
    mirrored rule."""
    order = int(round(math.sqrt(u.shape[1])))
    yi = sh_basis(factors.dirs_in, order, check=False)
    yo = sh_basis(factors.dirs_out, order, check=False)
    lower = factors.dirs_in * np.array([1.0, 1.0, -1.0])
    yl = sh_basis(lower, order, check=False)
    a, b = factors.weights_in, factors.weights_out
    approx_up = (yi @ u.T) @ (yo @ w.T).T
    approx_lo = (yl @ u.T) @ (yo @ w.T).T
    err = (a[:, None] * (approx_up - table) ** 2 * b[None, :]).sum() + (a[:, None] * approx_lo**2 * b[None, :]).sum()
    norm = (a[:, None] * table**2 * b[None, :]).sum()
    return math.sqrt(err / norm) if norm > 0 else 0.0

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

Factorisation order (:data:`FACTOR_ORDERS`, :func:`factor_sh`, the one owner of the rule):

* ``"before"`` (Kautz & McCool, seed 003): the SVD of the tabulated ``f~`` above, each factor then projected to SH
  (:func:`factor_brdf` + :func:`project_factors`): the truncation is optimal for ``f~`` itself, not for what the
  order-``n`` shading keeps of it;
* ``"after"`` (seed 001, "we decompose the BRDF matrix after spherical harmonic projection"): first the
  untruncated order-``n`` operator ``T (C, C)`` (:func:`full_operator`: per tabulated view direction, the
  light-side lobe projected to SH over the sphere; then each light coefficient's view dependence fitted to SH over
  the upper hemisphere), then the SVD of ``R T`` with ``R`` (:func:`view_metric`) the Cholesky factor of the view
  SH's hemisphere Gram matrix, so that ``||R E||_F = ||E||`` in the norm the shading sees (view over the
  hemisphere, light in SH coefficients): the ``k``-term truncation is the best rank-``k`` approximation of ``T``
  in that norm (Eckart-Young). Rank ``<= C``: ``k >= C`` is ``T`` exactly.

Both give RPO factors ``u, w (k, C)`` with ``T ~= w^T u``; :func:`operator_error` measures either against ``T``.

numpy only.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from prt_torch.errors import PrtError, warn
from prt_torch.sh.basis import check_order, sh_basis
from prt_torch.shapes import check_shape

#: default tabulation resolution: Gauss-Legendre nodes in cos(theta) x azimuths (per direction set)
DEFAULT_N_THETA = 24
DEFAULT_N_PHI = 48
#: BRDF terms ``k`` of a factorisation, of an RPO and of the exported shading graphs by default (``prt export
#: --terms``). Measured by ``prt bench rpo`` (docs/DESIGN.md, "RPO terms and factorisation order"): the fewest terms
#: whose image PSNR against the Monte-Carlo reference is within 0.15 dB of the untruncated order-4 operator for every
#: catalogue BRDF ("after"; k = 4 loses up to 3.1 dB on ward); k = 16 gains nothing measurable for twice ``M``.
DEFAULT_TERMS = 8
#: factorisation orders (module docstring): SVD of the tabulated BRDF, or of its SH projection
FACTOR_ORDERS = ("before", "after")
#: the factorisation order of every RPO built by default: ``"after"`` (optimal in the norm the shading sees, same
#: bytes and time; measured at k = 8 its radiance is 0.4-1.6 % off the untruncated operator vs 2.0-4.2 % "before")
DEFAULT_FACTOR_ORDER = "after"


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


def sh_rule_error(dirs_in: np.ndarray, weights_in: np.ndarray, dirs_out: np.ndarray, weights_out: np.ndarray,
                  u: np.ndarray, w: np.ndarray, table: np.ndarray) -> float:
    """Relative L2 error of ``sum_b (u_b . y(wi)) (w_b . y(wo))`` (``u, w (k, C)``) vs the table ``f~ (Ni, No)``
    over (sphere of ``wi``) x (hemisphere of ``wo``); the lower ``wi`` hemisphere (where ``f~ = 0``) uses the
    mirrored rule."""
    order = int(round(math.sqrt(u.shape[1])))
    yi = sh_basis(dirs_in, order, check=False)
    yo = sh_basis(dirs_out, order, check=False)
    lower = dirs_in * np.array([1.0, 1.0, -1.0])
    yl = sh_basis(lower, order, check=False)
    a, b = weights_in, weights_out
    approx_up = (yi @ u.T) @ (yo @ w.T).T
    approx_lo = (yl @ u.T) @ (yo @ w.T).T
    err = (a[:, None] * (approx_up - table) ** 2 * b[None, :]).sum() + (a[:, None] * approx_lo**2 * b[None, :]).sum()
    norm = (a[:, None] * table**2 * b[None, :]).sum()
    return math.sqrt(err / norm) if norm > 0 else 0.0


def check_factor_order(factor_order: str) -> str:
    """``factor_order`` if it is one of :data:`FACTOR_ORDERS`, else a one-line :class:`PrtError`."""
    if factor_order not in FACTOR_ORDERS:
        raise PrtError(f"unknown BRDF factorisation order {factor_order!r}: expected one of {', '.join(FACTOR_ORDERS)}")
    return factor_order


def view_metric(dirs_out: np.ndarray, weights_out: np.ndarray, order: int) -> np.ndarray:
    """``R (C, C)`` upper triangular with ``R^T R = Y^T diag(b) Y`` (the view SH's Gram matrix over the hemisphere
    rule ``dirs_out (No, 3)``, ``weights_out (No,)``): ``||R e||`` is the hemisphere L2 norm of ``e . y(wo)``."""
    check_order(order)
    yo = sh_basis(dirs_out, order, check=False) * np.sqrt(weights_out)[:, None]
    r = np.linalg.qr(yo, mode="r")
    return r * np.where(np.diag(r) < 0, -1.0, 1.0)[:, None]  # unique factor: positive diagonal


def full_operator(table: np.ndarray, dirs: np.ndarray, weights: np.ndarray, order: int) -> np.ndarray:
    """The untruncated order-``n`` operator ``T (C_o, C_i)`` of the table ``f~ (N, N)`` on the hemisphere rule
    ``dirs (N, 3)``, ``weights (N,)`` (both directions): ``P[j] = sum_i a_i f~(wi_i, wo_j) y(wi_i)`` (the light-side
    lobe projected over the sphere; ``f~ = 0`` below the horizon), then ``T`` the hemisphere least-squares fit of
    ``P`` in ``y(wo)``: ``L(wo) ~= sum y_co(wo) T[co, ci] <light product>_ci``. No SVD anywhere."""
    check_order(order)
    y = sh_basis(dirs, order, check=False)
    p = table.T @ (weights[:, None] * y)  # (No, C_i)
    sw = np.sqrt(weights)
    coef, *_ = np.linalg.lstsq(y * sw[:, None], p * sw[:, None], rcond=None)
    return coef  # (C_o, C_i)


def operator_error(T: np.ndarray, u: np.ndarray, w: np.ndarray, R: np.ndarray) -> float:
    """Relative error ``||R (T - w^T u)||_F / ||R T||_F`` of factors ``u, w (k, C)`` against the operator ``T (C, C)``
    in the view-hemisphere x light-SH norm (``R``: :func:`view_metric`)."""
    norm = float(np.linalg.norm(R @ T))
    return float(np.linalg.norm(R @ (T - w.T @ u))) / norm if norm > 0 else 0.0


@dataclass
class SHFactors:
    """``k`` SH-domain terms ``T ~= w^T u`` of a BRDF's order-``n`` operator.

    Attributes:
        u: ``(k, C)`` light factors' SH; w: ``(k, C)`` view factors' SH.
        singular_values: the factorisation's leading singular values (``"before"``: of the weighted table;
            ``"after"``: of ``R T``; at most ``C`` for ``"after"``).
        rel_error: relative error of the truncation in the norm that order factors in (``"before"``: ``f~`` over
            hemisphere x hemisphere; ``"after"``: :func:`operator_error`).
        operator_error: :func:`operator_error` against the untruncated operator (comparable across orders).
        factors: the tabulated factors (``"before"`` only, else ``None``).
    """

    u: np.ndarray
    w: np.ndarray
    singular_values: np.ndarray
    rel_error: float
    operator_error: float
    factors: BRDFFactors | None = None


def factor_sh(brdf: object, order: int, k: int = DEFAULT_TERMS, factor_order: str = DEFAULT_FACTOR_ORDER,
              n_theta: int = DEFAULT_N_THETA, n_phi: int = DEFAULT_N_PHI, table: np.ndarray | None = None,
              quiet: bool = False) -> SHFactors:
    """The ``k``-term SH factors of a BRDF at SH ``order`` by ``factor_order`` (module docstring).

    ``"after"`` with ``k > C`` is the exact operator plus ``k - C`` zero terms (one ``warning:`` line unless
    ``quiet``). ``table``: optional precomputed :func:`tabulate` output on the rule.
    """
    check_factor_order(factor_order)
    check_order(order)
    if not isinstance(k, int) or isinstance(k, bool) or k < 1:
        raise PrtError(f"number of BRDF terms k must be a positive integer, got {k!r}")
    dirs, wts = hemisphere_rule(n_theta, n_phi)
    F = tabulate(brdf, dirs, dirs) if table is None else np.asarray(table, dtype=np.float64)
    check_shape(F, (len(wts), len(wts)), name="BRDF table")
    T = full_operator(F, dirs, wts, order)
    R = view_metric(dirs, wts, order)
    if factor_order == "before":
        f = factor_brdf(brdf, k, n_theta, n_phi, table=F)
        u, w = project_factors(f, order)
        return SHFactors(u, w, f.singular_values, f.rel_error, operator_error(T, u, w, R), f)
    c = order * order
    if k > c and not quiet:
        warn(f"{k} BRDF terms exceed the rank {c} of the order-{order} operator: factor_order 'after' pads "
             f"{k - c} zero terms (k = {c} is already exact)")
    U, S, Vt = np.linalg.svd(R @ T)
    m = min(k, c)
    r = np.sqrt(S[:m])
    u = np.zeros((k, c))
    w = np.zeros((k, c))
    u[:m] = Vt[:m] * r[:, None]
    w[:m] = np.linalg.solve(R, U[:, :m] * r[None, :]).T
    # deterministic signs, as "before": each light factor integrates to a non-negative value (its y_00 coefficient)
    sgn = np.where(u[:, 0] < 0, -1.0, 1.0)[:, None]
    u, w = u * sgn, w * sgn
    total = float(np.sum(S**2))
    rel = float(np.sqrt(max(total - float(np.sum(S[:m] ** 2)), 0.0) / total)) if total > 0 else 0.0
    return SHFactors(u, w, S[:m], rel, operator_error(T, u, w, R), None)

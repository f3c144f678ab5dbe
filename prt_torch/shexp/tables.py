"""Precomputed tables of SH exponentiation (Ren et al. 2006): log-visibility of one sphere, OL coefficients.

Everything here is float64 numpy/scipy, computed once per order and cached (a fraction of a second).

**Exponential.** Ren's SH exponential is the product series ``exp*(f) = sum_k f^{*k} / k!`` with the
projected SH product ``*`` (``prt_torch.sh.product``). Its exact value is ``expm(M(f)) @ 1`` where
``M(f)`` is the ``(C, C)`` SH product matrix of ``f`` and ``1 = sqrt(4 pi) e_0`` the constant function
(:func:`exp_reference`). For zonal ``f`` the ``m = 0`` block of ``M`` is closed, so the log table works
with ``(n, n)`` matrices.

**Log of one sphere.** A sphere of angular radius ``alpha`` seen along ``+z`` leaves the visibility
``g(w) = [w_z < cos alpha]`` whose log is ``-inf`` on the cap. Following Ren 2006 (sec. 5) the log
vector is not the projection of ``log g`` but the *optimal* zonal ``f`` whose SH exponential best
matches the order-``n`` projection of ``g``::

    f(alpha) = argmin_f || exp*(f) - P_n g ||^2 + lambda ||f||^2      (lambda = LOG_RIDGE = 1e-4)

The small ridge is our addition: without it the optimum diverges as ``alpha -> pi/2`` (the order-``n``
truncated series needs ever larger cancelling terms to approach a hemisphere step). With it, ``exp*`` of
the tabulated log reproduces ``P_n g`` to a few per cent for every radius (tests compare it with
quadrature of the exact cap) while ``||f||`` stays O(10), so sums over many spheres stay tame.
The table has ``N_ALPHA`` rows uniform in ``alpha`` on ``[0, pi/2]`` (``f(0) = 0``), in the project's
ZH convention (``g_l``, :mod:`prt_torch.sh.zonal`). The run time reads it resampled
(:func:`cos_log_table`): ``N_COS`` rows uniform in ``t = cos(alpha)`` -- the variable the receiver/sphere geometry
gives without trigonometry (``t = sqrt(d^2 - r^2) / d``) and in which the cap's coefficients are polynomials,
so the nearest row is within ~1e-4 relative of the linear interpolation in ``alpha`` -- one gather per band.

**Optimal linear (OL).** With the DC isolated (``exp(f) = exp(f_0 / sqrt(4 pi)) exp*(f^)``, ``f^`` = ``f``
with ``f_0 = 0``), ``exp*(f^) ~= a(m) 1 + b(m) f^`` with ``m = ||f^||``. ``a, b`` minimise the squared
error of that approximation against :func:`exp_reference` over a fixed training set of typical
DC-free log vectors (single spheres of every tabulated radius, sums of 2-6 spheres in random directions
and radii) each rescaled to magnitude ``m`` (Ren 2006 sec. 4.2). Tabulated at ``m_i = M_MAX (i / (N-1))^2``
(fine near 0, where HYB evaluates it).
"""

from __future__ import annotations

import contextlib
import functools
import math
from collections.abc import Iterator

import numpy as np

from prt_torch.errors import PrtError
from prt_torch.scene.shexp_kernel import OL_MAX
from prt_torch.sh.basis import check_order, num_coeffs, sh_index
from prt_torch.sh.product import dense_gaunt
from prt_torch.sh.quadrature import sphere_directions
from prt_torch.sh.zonal import zh_band_scale, zh_to_sh

N_ALPHA = 512
"""Rows of the log-visibility table (uniform in angular radius on ``[0, pi/2]``)."""
N_COS = 8192
"""Rows of the run-time log table (:func:`cos_log_table`), uniform in ``cos(alpha)`` on ``[0, 1]``."""
N_OL = 256
"""Rows of the OL coefficient table."""





@contextlib.contextmanager
def _one_thread() -> Iterator[None]:
    """Small batched float64 work runs fastest (and politest) on one torch thread."""
    import torch

    n = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        yield
    finally:
        torch.set_num_threads(n)


def cap_complement_zh(alpha: np.ndarray, order: int) -> np.ndarray:
    """Closed-form ZH coefficients ``g_l = 2 pi int_{-1}^{cos alpha} P_l`` of ``[w . s < cos alpha]``.

    ``alpha (A,)`` angular radii in radians -> ``(A, n)`` float64 (project ZH convention).
    """
    x = np.cos(np.asarray(alpha, dtype=np.float64))
    p = np.polynomial.legendre.legvander(x, order)  # (A, n+1): P_0..P_n
    out = np.empty((x.size, order))
    out[:, 0] = x + 1.0
    for l in range(1, order):
        out[:, l] = (p[:, l + 1] - p[:, l - 1]) / (2 * l + 1)
    return 2 * math.pi * out


@functools.cache
def _zonal_gaunt(order: int) -> np.ndarray:
    """``(n, n, n)`` Gaunt tensor restricted to the ``m = 0`` coefficients (axial ZH about +z)."""
    idx = [sh_index(l, 0) for l in range(order)]
    g = dense_gaunt(order)
    return np.ascontiguousarray(g[np.ix_(idx, idx, idx)])


def exp_reference(f: np.ndarray) -> np.ndarray:
    """Brute-force SH exponential ``expm(M(f)) @ 1`` of ``f (..., C)`` (float64; scipy.linalg.expm)."""
    import scipy.linalg

    from prt_torch.sh.product import product_matrix

    f = np.asarray(f, dtype=np.float64)
    m = product_matrix(f)
    one = np.zeros(f.shape[-1])
    one[0] = math.sqrt(4 * math.pi)
    flat = m.reshape(-1, f.shape[-1], f.shape[-1])
    out = np.stack([scipy.linalg.expm(a) @ one for a in flat])
    return out.reshape(f.shape)


LOG_RIDGE = 1e-4
"""Ridge weight ``lambda`` of the log fit (module doc): bounds ``||f||`` near ``alpha = pi/2``."""


@functools.cache
def log_visibility_table(order: int, n: int = N_ALPHA) -> np.ndarray:
    """``(n, order)`` float64 ZH coefficients ``g_l`` of the log-visibility of one sphere, row ``i`` at angular
    radius ``alpha_i = (pi/2) i / (n-1)`` (module doc for the definition). Read-only, cached.

    All rows are solved at once by a batched Levenberg-Marquardt (torch, float64, Jacobian by forward-mode
    autodiff through ``matrix_exp``) of ``||exp*(f) - P_n g||^2 + LOG_RIDGE ||f||^2`` in axial coefficients.
    Without the ridge the optimum runs off to ``||f|| ~ 1e4`` as the cap approaches a hemisphere (the
    truncated product series then cancels huge terms); with it the relative residual stays below ~5 %
    and ``||f|| < 10`` (order 4).
    """
    import torch

    check_order(order, 8)
    if not isinstance(n, int) or n < 2:
        raise PrtError(f"log table size must be an integer >= 2, got {n!r}")
    alphas = np.linspace(0.0, math.pi / 2, n)
    scale = zh_band_scale(order)
    tgt = torch.from_numpy(cap_complement_zh(alphas, order) / scale)
    gz = torch.from_numpy(_zonal_gaunt(order))
    one = torch.zeros(order, dtype=torch.float64)
    one[0] = math.sqrt(4 * math.pi)

    def expz(z: torch.Tensor) -> torch.Tensor:
        return torch.linalg.matrix_exp(torch.einsum("k,ijk->ij", z, gz)) @ one

    jac = torch.func.vmap(torch.func.jacfwd(expz))
    expb = torch.func.vmap(expz)
    lam = LOG_RIDGE
    eye = torch.eye(order, dtype=torch.float64)

    def cost(z: torch.Tensor) -> torch.Tensor:
        return ((expb(z) - tgt) ** 2).sum(1) + lam * (z**2).sum(1)

    z = torch.zeros(n, order, dtype=torch.float64)
    mu = torch.full((n,), 1e-2, dtype=torch.float64)
    with torch.no_grad(), _one_thread():
        c = cost(z)
        for _ in range(60):  # LM iterations (a loop over iterations, not over rows)
            r = expb(z) - tgt
            jm = jac(z)
            a = jm.transpose(1, 2) @ jm + lam * eye
            g = jm.transpose(1, 2) @ r[..., None] + lam * z[..., None]
            damp = torch.diag_embed(torch.diagonal(a, dim1=1, dim2=2) + 1e-12) * mu[:, None, None]
            zn = z - torch.linalg.solve(a + damp, g)[..., 0]
            cn = cost(zn)
            ok = cn < c
            z = torch.where(ok[:, None], zn, z)
            c = torch.where(ok, cn, c)
            mu = torch.where(ok, mu / 3, mu * 4)
    out = z.numpy() * scale
    out[0] = 0.0
    out.setflags(write=False)
    return out


@functools.cache
def cos_log_table(order: int, n: int = N_COS) -> np.ndarray:
    """``(n + 1, order)`` float32 run-time log table: row ``i < n`` is :func:`log_visibility_table` (linear in
    ``alpha``) at ``alpha = acos(i / (n - 1))``; row ``n`` is zero (the row of receivers inside the sphere,
    which contributes nothing). Read at the nearest row: the largest step from the linear interpolation in
    ``alpha`` is ~3e-3 on values up to ~20 (order 4, ``n`` = 8192). Read-only, cached."""
    if not isinstance(n, int) or n < 2:
        raise PrtError(f"cos log table size must be an integer >= 2, got {n!r}")
    table = log_visibility_table(order)
    alphas = np.linspace(0.0, math.pi / 2, table.shape[0])
    at = np.arccos(np.linspace(0.0, 1.0, n))
    out = np.zeros((n + 1, order), dtype=np.float32)
    for l in range(order):  # a loop over bands
        out[:n, l] = np.interp(at, alphas, table[:, l])
    out.setflags(write=False)
    return out


def _training_logs(order: int, count: int, seed: int = 0) -> np.ndarray:
    """``(count, C)`` DC-free log vectors: single spheres plus sums of 2-6 spheres in random directions."""
    rng = np.random.default_rng(seed)
    table = log_visibility_table(order)
    rows = rng.integers(1, table.shape[0], size=(count, 6))
    n_sph = np.where(np.arange(count) < count // 4, 1, rng.integers(2, 7, size=count))
    use = np.arange(6)[None, :] < n_sph[:, None]
    axes = sphere_directions(count * 6, seed=seed).reshape(count, 6, 3)
    axes = axes[rng.permutation(count)]
    f = zh_to_sh(table[rows] * use[..., None], axes).sum(1)
    f[:, 0] = 0.0
    return f


@functools.cache
def ol_table(order: int, n: int = N_OL, m_max: float = OL_MAX, n_train: int = 96) -> np.ndarray:
    """``(n, 2)`` float64 optimal-linear coefficients ``(a, b)`` at magnitudes ``m_i = m_max (i/(n-1))^2``.

    Least squares of ``exp*(f^) ~= a 1 + b f^`` over the training vectors rescaled to each ``m_i``
    (module doc). Row 0 (``m = 0``) is ``(1, 1)``. Read-only, cached.
    """
    import torch

    from prt_torch.sh.product import product_matrix

    check_order(order, 8)
    c = num_coeffs(order)
    f = _training_logs(order, n_train)
    f = f / np.maximum(np.linalg.norm(f, axis=1, keepdims=True), 1e-300)
    mags = m_max * (np.arange(n) / (n - 1)) ** 2
    out = np.empty((n, 2))
    out[0] = (1.0, 1.0)
    one = torch.zeros(c, dtype=torch.float64)
    one[0] = math.sqrt(4 * math.pi)
    fm = torch.from_numpy(f)
    with torch.no_grad(), _one_thread():
        for i in range(1, n):
            x = fm * mags[i]  # (T, C)
            e = torch.linalg.matrix_exp(product_matrix(x)) @ one  # (T, C)
            # minimise sum ||e - a 1 - b x||^2: DC row fixes a (x has no DC), the rest fixes b
            a = e[:, 0].mean() / one[0]
            b = (e[:, 1:] * x[:, 1:]).sum() / (x[:, 1:] ** 2).sum()
            out[i] = (float(a), float(b))
    out.setflags(write=False)
    return out

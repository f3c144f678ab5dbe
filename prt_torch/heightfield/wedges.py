"""Canonical visibility wedges tabulated once as SH, and their z-rotations (seed 003 eq. 4-5, after [SN08]).

The canonical wedge of ``n`` wedges is the region of azimuth ``|phi| <= pi / n`` (about ``+x``) below the
elevation ``x`` (world frame, ``z`` up):

    W_c(x) = int_{-pi/n}^{pi/n} int_{-pi/2}^{x} y_c(cos e cos phi, cos e sin phi, sin e) cos e de dphi,

the SH projection of the wedge's indicator, a function of one angle ``x in [-pi/2, pi/2]``. It is tabulated on
a uniform grid of ``K`` elevations by Gauss-Legendre quadrature (the integrand is a trigonometric polynomial
of degree ``< order`` in ``e`` and ``phi``: ``GL_E`` nodes per elevation interval and ``GL_PHI`` over the
azimuth make it exact to float64 rounding), accumulated interval by interval. :meth:`WedgeTable.lookup`
reads it back by linear interpolation (error ``O((pi / K)^2)``); the run-time path reads the nearest row
(elevation error ``<= pi / (2 (K - 1))``, 7.7e-4 rad = 0.044 deg at ``K = 2049``).

Wedge ``i`` (centred on ``phi_i = 2 pi i / n``, :func:`prt_torch.heightfield.horizon.wedge_azimuths`) is the
canonical one rotated about ``+z``: ``R_z(phi_i) W(x)`` with the SH rotation ``D(R_z(phi_i))``
(:func:`prt_torch.sh.rotation.sh_rotation`, a per-band 2x2 rotation of each ``(m, -m)`` pair). The wedge
azimuths are the same for every vertex, so the rotation is folded into the table once:
``T[i, k] = D(R_z(phi_i)) W(x_k)``, and eq. 5 becomes a gather-and-sum of rows of ``T``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from prt_torch.heightfield.horizon import check_wedges, wedge_azimuths
from prt_torch.sh.basis import check_order, sh_basis
from prt_torch.sh.quadrature import rotations_about_z
from prt_torch.sh.rotation import sh_rotation

#: elevation samples of the table (the run-time lookup reads the nearest one: at most pi / 16384 rad off)
TABLE_BINS = 2049
#: Gauss-Legendre nodes per elevation interval and over the wedge's azimuth
GL_E, GL_PHI = 4, 24


def canonical_wedge(order: int, n_wedges: int, bins: int = TABLE_BINS) -> tuple[np.ndarray, np.ndarray]:
    """``(elevations (K,), W (K, C))`` float64: the canonical wedge's SH below each elevation (module docstring)."""
    check_order(order)
    n_wedges = check_wedges(n_wedges)
    k = int(bins)
    x = np.linspace(-np.pi / 2, np.pi / 2, k)
    ze, we = np.polynomial.legendre.leggauss(GL_E)
    zp, wp = np.polynomial.legendre.leggauss(GL_PHI)
    half = np.pi / n_wedges
    phi, wphi = zp * half, wp * half  # nodes on [-half, half]
    a, b = x[:-1], x[1:]
    e = 0.5 * (a + b)[:, None] + 0.5 * (b - a)[:, None] * ze[None]  # (K-1, GL_E)
    w_e = 0.5 * (b - a)[:, None] * we[None] * np.cos(e)  # cos e: the solid-angle element
    ce = np.cos(e)[..., None]
    dirs = np.stack(np.broadcast_arrays(ce * np.cos(phi), ce * np.sin(phi), np.sin(e)[..., None]), axis=-1)
    y = sh_basis(dirs.reshape(-1, 3), order, check=False).reshape(k - 1, GL_E, GL_PHI, -1)
    per_interval = np.einsum("ijpc,ij,p->ic", y, w_e, wphi)
    table = np.zeros((k, order * order))
    table[1:] = np.cumsum(per_interval, axis=0)
    return x, table


@dataclass(frozen=True)
class WedgeTable:
    """The rotated wedge tables of one ``(order, n_wedges)``.

    Attributes:
        elevations: ``(K,)`` float64 uniform grid on ``[-pi/2, pi/2]``.
        canonical: ``(K, C)`` float64 the canonical wedge (:func:`canonical_wedge`).
        rotated: ``(n, K, C)`` float64 ``D(R_z(phi_i)) canonical[k]``.
        azimuths: ``(n,)`` wedge centres.
    """

    elevations: np.ndarray
    canonical: np.ndarray
    rotated: np.ndarray
    azimuths: np.ndarray

    @classmethod
    def make(cls, order: int, n_wedges: int, bins: int = TABLE_BINS) -> WedgeTable:
        x, w = canonical_wedge(order, n_wedges, bins)
        az = wedge_azimuths(n_wedges)
        d = sh_rotation(rotations_about_z(az), order)  # (n, C, C)
        return cls(x, w, np.einsum("icd,kd->ikc", d, w), az)

    @property
    def order(self) -> int:
        return int(round(np.sqrt(self.canonical.shape[1])))

    @property
    def n_wedges(self) -> int:
        return int(self.rotated.shape[0])

    def lookup(self, angles: np.ndarray) -> np.ndarray:
        """``(..., n) -> (..., n, C)``: each wedge's SH below the given elevations (linear interpolation;
        numpy reference of the torch path in :mod:`prt_torch.heightfield.visibility`)."""
        a = np.clip(np.asarray(angles, dtype=np.float64), -np.pi / 2, np.pi / 2)
        k = self.elevations.shape[0]
        t = (a + np.pi / 2) / np.pi * (k - 1)
        k0 = np.clip(np.floor(t).astype(np.int64), 0, k - 2)
        f = (t - k0)[..., None]
        i = np.arange(self.n_wedges)
        return (1 - f) * self.rotated[i, k0] + f * self.rotated[i, k0 + 1]

"""Dipole subsurface transfer vs Jensen et al. 2001's closed forms (written independently here with sympy),
numerical integrals (scipy quad), a brute-force dense kernel, and a flat semi-infinite slab."""

from __future__ import annotations

import math

import numpy as np
import pytest
import sympy
from scipy.integrate import quad
from scipy.spatial.distance import cdist

from prt_torch.bake.subsurface import (
    DipoleParams,
    dipole_disk,
    dipole_kernel,
    dipole_Rd,
    dipole_total,
    single_scatter_weight,
    subsurface_transfer,
    vertex_areas,
)
from prt_torch.errors import PrtError

SKIN = dict(sigma_a=0.032, sigma_s_prime=0.74, eta=1.3)  # Jensen 2001 skin1, red channel (1/mm)
SKIN_GREEN = dict(sigma_a=0.17, sigma_s_prime=0.88, eta=1.3)
MARBLE = dict(sigma_a=0.0041, sigma_s_prime=2.62, eta=1.5)  # marble, green channel


def _sympy_Rd(sigma_a: float, sigma_s_prime: float, eta: float):
    """Jensen 2001 eq. (paper notation) as a sympy expression in r."""
    r = sympy.Symbol("r", nonnegative=True)
    sa, ss, n = sympy.Float(sigma_a), sympy.Float(sigma_s_prime), sympy.Float(eta)
    st = sa + ss
    alpha = ss / st
    str_ = sympy.sqrt(3 * sa * st)
    fdr = -sympy.Float(1.44) / n**2 + sympy.Float(0.71) / n + sympy.Float(0.668) + sympy.Float(0.0636) * n
    A = (1 + fdr) / (1 - fdr)
    zr = 1 / st
    zv = zr * (1 + sympy.Rational(4, 3) * A)
    dr = sympy.sqrt(r**2 + zr**2)
    dv = sympy.sqrt(r**2 + zv**2)
    expr = alpha / (4 * sympy.pi) * (zr * (str_ * dr + 1) * sympy.exp(-str_ * dr) / dr**3
                                     + zv * (str_ * dv + 1) * sympy.exp(-str_ * dv) / dv**3)
    return sympy.lambdify(r, expr, "numpy"), float(alpha), float(A)


@pytest.mark.parametrize("mat", [SKIN, MARBLE], ids=["skin", "marble"])
def test_Rd_matches_the_closed_form(mat) -> None:
    ref, _, _ = _sympy_Rd(**mat)
    r = np.concatenate([[0.0], np.geomspace(1e-3, 30.0, 60)])
    np.testing.assert_allclose(dipole_Rd(r, **mat), ref(r), rtol=1e-12)


@pytest.mark.parametrize("mat", [SKIN, MARBLE], ids=["skin", "marble"])
def test_total_and_disk_integrals(mat) -> None:
    p = DipoleParams(**mat)
    _, a, A = _sympy_Rd(**mat)
    s = math.sqrt(3 * (1 - a))
    jensen = a / 2 * (1 + math.exp(-4 / 3 * A * s)) * math.exp(-s)  # Jensen 2001's total diffuse reflectance
    assert dipole_total(p) == pytest.approx(jensen, rel=1e-12)
    f = lambda r: 2 * math.pi * r * float(dipole_Rd(r, **mat))  # noqa: E731
    num = quad(f, 0, 1, limit=200)[0] + quad(f, 1, np.inf, limit=200)[0]
    assert num == pytest.approx(jensen, rel=1e-7)
    for rho in (0.05, 0.7, 3.0):
        assert float(dipole_disk(rho, p)) == pytest.approx(quad(f, 0, rho, limit=200)[0], rel=1e-8)


def test_kernel_matches_brute_force() -> None:
    rng = np.random.default_rng(0)
    p = DipoleParams(scale=10.0, cutoff=3.0, **SKIN)  # positions in cm
    x = rng.uniform(0, 1.5, size=(300, 3))
    a = rng.uniform(0.001, 0.004, size=300)
    K = dipole_kernel(x, a, p).toarray()
    d = cdist(x, x) * p.scale
    ref = np.where((d < p.radius_mm) & (d > 0), dipole_Rd(d, **SKIN) * (a[None, :] * p.scale**2), 0.0)
    np.fill_diagonal(ref, dipole_disk(np.sqrt(a * p.scale**2 / math.pi), p))
    np.testing.assert_allclose(K, ref, rtol=1e-12, atol=1e-15)
    assert (ref > 0).sum() > 2 * 300  # neighbours really contribute


def _slab(h: float, n: int) -> tuple[np.ndarray, np.ndarray]:
    """An ``n x n`` grid of spacing ``h`` in the plane z = 0 (triangulated)."""
    i, j = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
    pos = np.stack([i.ravel() * h, j.ravel() * h, np.zeros(n * n)], 1)
    q = (i[:-1, :-1] * n + j[:-1, :-1]).ravel()
    faces = np.concatenate([np.stack([q, q + n, q + 1], 1), np.stack([q + 1, q + n, q + n + 1], 1)])
    return pos, faces


@pytest.mark.parametrize("mat", [SKIN, SKIN_GREEN], ids=["skin-red", "skin-green"])
def test_flat_slab_reflects_the_total_diffuse_reflectance(mat) -> None:
    """A uniformly lit flat slab (t = the clamped-cosine transfer of a horizontal vertex, the same everywhere):
    subsurface = (1 - F_dr)^2 R_d t away from the edges, with R_d = Jensen's total diffuse reflectance."""
    p = DipoleParams(scale=1.0, cutoff=5.0, single=False, **mat)  # positions in mm
    h = min(p.radius_mm / 25, p.z_r / 2)  # resolve the source depth and the diffusion length
    n = 2 * math.ceil(p.radius_mm / h) + 5
    pos, faces = _slab(h, n)
    areas = vertex_areas(pos, faces)
    t = np.tile(np.array([0.886, 0.0, 1.023, 0.0]) / math.pi, (len(pos), 1))
    s = subsurface_transfer(pos, areas, t, p)
    centre = (n // 2) * n + n // 2
    ref = (1 - p.F_dr) ** 2 * dipole_total(p) * t[centre]
    np.testing.assert_allclose(s[centre], ref, rtol=0.01)
    assert s[0, 0] < 0.8 * s[centre, 0]  # a corner sees a quarter plane


def test_single_scatter_weight_vs_quadrature() -> None:
    p = DipoleParams(**SKIN)
    for mu in (0.1, 0.5, 1.0):
        mu_t = math.sqrt(1 - (1 - mu * mu) / p.eta**2)
        avg = quad(lambda mo, mu=mu, mu_t=mu_t: 2 * mo * mu / (mu_t + mo), 0, 1)[0]  # cosine-weighted exit mean
        ref = p.alpha_prime * (1 - p.F_dr) ** 2 / (4 * math.pi * p.eta**2) * avg
        assert float(single_scatter_weight(np.array(mu), p)) == pytest.approx(ref, rel=1e-10)


def test_vertex_areas_sum_to_mesh_area() -> None:
    pos, faces = _slab(0.5, 7)
    a = vertex_areas(pos, faces)
    assert a.sum() == pytest.approx(9.0, rel=1e-12)  # (6 * 0.5)^2


@pytest.mark.parametrize("bad", [
    lambda: DipoleParams(sigma_a=0.0),
    lambda: DipoleParams(eta=0.5),
    lambda: DipoleParams(scale=float("nan")),
    lambda: DipoleParams.from_dict({"sigma_x": 1.0}),
    lambda: dipole_Rd(-1.0, **SKIN),
    lambda: subsurface_transfer(np.zeros((3, 3)), np.ones(3), np.zeros((2, 4)), DipoleParams()),
    lambda: subsurface_transfer(np.zeros((3, 3)), np.ones(3), np.zeros((3, 4)), {"sigma_a": 1}),
    lambda: vertex_areas(np.zeros((3, 2)), np.zeros((1, 3), int)),
])
def test_bad_inputs_are_one_line_errors(bad) -> None:
    with pytest.raises(PrtError) as e:
        bad()
    assert "\n" not in str(e.value)

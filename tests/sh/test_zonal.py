"""Zonal harmonics vs Ramamoorthi-Hanrahan closed forms, scipy quad, and sphere quadrature."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from scipy.integrate import quad
from scipy.special import eval_legendre

from prt_torch.errors import PrtError
from prt_torch.sh.basis import sh_basis, sh_index
from prt_torch.sh.project import project
from prt_torch.sh.quadrature import hemisphere_directions, sphere_quadrature
from prt_torch.sh.zonal import (
    clamped_cosine_zh,
    hemisphere_zh,
    irradiance_sh,
    lobes_to_sh,
    rotate_zh,
    zh_band_scale,
    zh_from_axial,
    zh_project,
    zh_to_axial,
    zh_to_sh,
)


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _quad_zh(h, order: int) -> np.ndarray:  # type: ignore[no-untyped-def]
    """Funk-Hecke g_l = 2 pi int h(t) P_l(t) dt with scipy's adaptive quad, split at the horizon."""
    return np.array([
        2 * math.pi * sum(quad(lambda t, l=l: h(t) * eval_legendre(l, t), a, b, epsabs=1e-14)[0]
                          for a, b in [(-1, 0), (0, 1)])
        for l in range(order)
    ])


def test_clamped_cosine_published_values() -> None:
    """R&H 2001: A_0 = pi, A_1 = 2pi/3, A_2 = pi/4, A_3 = 0, A_4 = -pi/24, A_5 = 0, A_6 = pi/64."""
    a = clamped_cosine_zh(7)
    ref = [math.pi, 2 * math.pi / 3, math.pi / 4, 0.0, -math.pi / 24, 0.0, math.pi / 64]
    np.testing.assert_allclose(a, ref, atol=1e-15)


def test_clamped_cosine_vs_scipy_quad_and_zh_project() -> None:
    ref = _quad_zh(lambda t: max(t, 0.0), 12)
    np.testing.assert_allclose(clamped_cosine_zh(12), ref, atol=1e-12)
    np.testing.assert_allclose(zh_project(lambda t: np.maximum(t, 0.0), 12), ref, atol=1e-12)


def test_hemisphere_zh_vs_quad_and_ray_sampling() -> None:
    ref = _quad_zh(lambda t: 1.0 if t >= 0 else 0.0, 10)
    np.testing.assert_allclose(hemisphere_zh(10), ref, atol=1e-12)
    np.testing.assert_allclose(zh_project(lambda t: (t >= 0).astype(float), 10), ref, atol=1e-12)
    # the bake's view: uniform hemisphere rays with weight 2pi/n, projected; vs the closed form about +z
    n = 20000
    d = hemisphere_directions(n)
    v = project(np.ones(n), d, np.full(n, 2 * math.pi / n), 4)
    np.testing.assert_allclose(v, zh_to_sh(hemisphere_zh(4), np.array([0.0, 0.0, 1.0])), atol=2e-3)


def test_zh_project_smooth_function_without_split() -> None:
    h = np.exp
    ref = _quad_zh(lambda t: math.exp(t), 8)
    np.testing.assert_allclose(zh_project(h, 8, n_points=32, split_at_horizon=False), ref, atol=1e-12)


def test_zh_to_sh_vs_sphere_projection() -> None:
    """Project h(s . w) over the sphere (exact Lebedev rule) and compare with f_lm = g_l y_lm(s)."""
    order = 5

    def h(t: np.ndarray) -> np.ndarray:  # degree 4: band-limited to order 5
        return 0.3 + t - 2 * t**2 + 0.5 * t**3 + 1.5 * t**4

    g = zh_project(h, order, split_at_horizon=False)
    s = _unit(np.array([0.3, -0.8, 0.5]))
    dirs, w = sphere_quadrature(2 * (order - 1))
    ref = project(h(dirs @ s), dirs, w, order)
    np.testing.assert_allclose(zh_to_sh(g, s), ref, atol=1e-12)
    assert rotate_zh is zh_to_sh


def test_axial_convention_roundtrip() -> None:
    g = np.random.default_rng(0).normal(size=(2, 6))
    zax = zh_to_axial(g)
    np.testing.assert_allclose(zh_from_axial(zax), g, atol=1e-15)
    # z_l is the y_l0 coefficient about +z
    f = zh_to_sh(g, np.array([[0.0, 0.0, 1.0]]))
    np.testing.assert_allclose(f[:, [sh_index(l, 0) for l in range(6)]], zax, atol=1e-15)
    np.testing.assert_allclose(zh_band_scale(3), [math.sqrt(4 * math.pi), math.sqrt(4 * math.pi / 3),
                                                  math.sqrt(4 * math.pi / 5)])


def test_zh_to_sh_batched_and_torch() -> None:
    rng = np.random.default_rng(1)
    g = rng.normal(size=(4, 3, 6))
    ax = _unit(rng.normal(size=(4, 1, 3)))
    f = zh_to_sh(g, ax)
    assert f.shape == (4, 3, 36)
    np.testing.assert_allclose(f[2, 1], g[2, 1][[l for l in range(6) for _ in range(2 * l + 1)]]
                               * sh_basis(ax[2, 0], 6), atol=1e-15)
    ft = zh_to_sh(torch.tensor(g, dtype=torch.float32), torch.tensor(ax, dtype=torch.float32))
    assert ft.dtype == torch.float32
    np.testing.assert_allclose(ft.numpy(), f, atol=1e-5)


def test_lobes_to_sh() -> None:
    rng = np.random.default_rng(2)
    dirs = _unit(rng.normal(size=(3, 3)))
    coeffs = rng.normal(size=(3, 4, 3))
    ref = sum(np.stack([zh_to_sh(coeffs[k, :, c], dirs[k]) for c in range(3)], axis=1) for k in range(3))
    np.testing.assert_allclose(lobes_to_sh(dirs, coeffs), ref, atol=1e-14)
    np.testing.assert_allclose(lobes_to_sh(torch.tensor(dirs), torch.tensor(coeffs)).numpy(), ref, atol=1e-14)


def test_irradiance_of_uniform_environment_is_pi() -> None:
    light = np.zeros((9, 3))
    light[0] = math.sqrt(4 * math.pi)  # L(w) = 1
    e = irradiance_sh(light)
    n = _unit(np.random.default_rng(3).normal(size=(10, 3)))
    np.testing.assert_allclose(sh_basis(n, 3) @ e, math.pi, atol=1e-14)
    et = irradiance_sh(torch.tensor(light))
    np.testing.assert_allclose(et.numpy(), e, atol=1e-15)


def test_irradiance_vs_brute_force_quadrature() -> None:
    """E(n) = int L(w) max(n.w, 0) dw by a 5810-point Lebedev sum (kinked integrand: ~1e-4 accurate)."""
    rng = np.random.default_rng(4)
    light = rng.normal(size=(9, 3))
    light[0] += 8.0
    dirs, w = sphere_quadrature(131)
    lvals = sh_basis(dirs, 3) @ light  # (N, 3)
    normals = _unit(rng.normal(size=(6, 3)))
    brute = np.einsum("vn,n,nc->vc", np.maximum(normals @ dirs.T, 0), w, lvals)
    got = sh_basis(normals, 3) @ irradiance_sh(light)
    np.testing.assert_allclose(got, brute, rtol=1e-3, atol=1e-3)


def test_bad_inputs() -> None:
    with pytest.raises(PrtError, match="unit"):
        zh_to_sh(np.ones(3), np.array([1.0, 1.0, 0.0]))
    with pytest.raises(PrtError, match="NaN"):
        zh_to_sh(np.array([np.nan, 1.0]), np.array([0.0, 0.0, 1.0]))
    with pytest.raises(PrtError, match="unsupported SH order"):
        zh_to_sh(np.ones((2, 0)), np.array([0.0, 0.0, 1.0]))
    with pytest.raises(PrtError, match="broadcast"):
        zh_to_sh(np.ones((4, 3)), _unit(np.ones((5, 3))))
    with pytest.raises(PrtError, match="shape"):
        zh_to_sh(np.ones(3), np.ones((2, 2)))
    with pytest.raises(PrtError, match="not a square"):
        irradiance_sh(np.ones((10, 3)))
    with pytest.raises(PrtError, match="unsupported SH order"):
        clamped_cosine_zh(0)
    with pytest.raises(PrtError, match="fn_of_cos"):
        zh_project(lambda t: np.ones(3), 4)
    with pytest.raises(PrtError, match="lobe coeffs"):
        lobes_to_sh(np.ones((2, 3)), np.ones((3, 4, 3)))

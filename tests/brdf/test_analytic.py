"""Analytic BRDFs: reciprocity, closed-form normalisations (scipy quadrature), energy conservation."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import integrate

from prt_torch.brdf.analytic import BlinnPhong, CookTorrance, Lambert, Phong, Ward, ggx_d
from prt_torch.brdf.factor import hemisphere_rule
from prt_torch.errors import PrtError

ALL = [Lambert(), Phong(exponent=20.0, kd=0.2, ks=0.8), BlinnPhong(exponent=40.0, kd=0.1, ks=0.9),
       CookTorrance(roughness=0.4, f0=0.9, kd=0.0, ks=1.0), Ward(alpha=0.2, kd=0.2, ks=0.8)]


def _upper(n: int, seed: int) -> np.ndarray:
    d = np.random.default_rng(seed).normal(size=(n, 3))
    d[:, 2] = np.abs(d[:, 2]) + 0.05
    return d / np.linalg.norm(d, axis=1, keepdims=True)


@pytest.mark.parametrize("brdf", ALL, ids=lambda b: b.name)
def test_reciprocity_positivity_horizon(brdf: object) -> None:
    wi, wo = _upper(500, 1), _upper(500, 2)
    a, b = brdf.shape(wi, wo), brdf.shape(wo, wi)
    np.testing.assert_allclose(a, b, rtol=1e-12)
    assert (a >= 0).all()
    below = wi * np.array([1, 1, -1])
    assert (brdf.shape(below, wo) == 0).all() and (brdf.shape(wo, below) == 0).all()
    np.testing.assert_allclose(brdf(wi, wo), a[:, None] * brdf.tint[None, :])


def _albedo(brdf: object, wo: np.ndarray) -> float:
    dirs, w = hemisphere_rule(64, 128)
    return float((brdf.shape(dirs, np.broadcast_to(wo, dirs.shape).copy()) * dirs[:, 2] * w).sum())


def test_lambert_and_phong_albedo_closed_form() -> None:
    z = np.array([0.0, 0.0, 1.0])
    assert _albedo(Lambert(), z) == pytest.approx(1.0, rel=1e-12)

    # normalised Phong at normal incidence: int (e+2)/(2pi) cos^e cos dw = 1 exactly (scipy, in theta)
    e = 20.0
    ref, _ = integrate.quad(lambda t: (e + 2) / (2 * math.pi) * math.cos(t) ** (e + 1) * math.sin(t) * 2 * math.pi,
                            0, math.pi / 2)
    assert ref == pytest.approx(1.0, rel=1e-10)
    assert _albedo(Phong(exponent=e, kd=0.25, ks=0.75), z) == pytest.approx(1.0, rel=1e-6)


def test_blinn_normal_incidence_albedo_is_one() -> None:
    for e in (1.0, 10.0, 40.0, 200.0):
        b = BlinnPhong(exponent=e)
        # wo = n: theta_h = theta_i / 2 (scipy quadrature in theta_i)
        ref, _ = integrate.quad(lambda t, b=b, e=e: b.norm * math.cos(t / 2) ** e * math.cos(t) * math.sin(t)
                                * 2 * math.pi, 0, math.pi / 2, epsabs=1e-13)
        assert ref == pytest.approx(1.0, rel=1e-9)
        assert b.norm == pytest.approx((e + 8) / (8 * math.pi), rel=0.25)


def test_ggx_distribution_normalised() -> None:
    for alpha in (0.05, 0.3, 0.8):
        val, _ = integrate.quad(lambda t, a=alpha: float(ggx_d(np.array(math.cos(t)), a)) * math.cos(t)
                                * math.sin(t) * 2 * math.pi, 0, math.pi / 2, epsabs=1e-12, limit=200)
        assert val == pytest.approx(1.0, rel=1e-8)


def test_cook_torrance_closed_form_at_normal_incidence() -> None:
    ct = CookTorrance(roughness=0.6, f0=0.3, kd=0.0, ks=1.0)
    z = np.array([[0.0, 0.0, 1.0]])
    # h = n, G1(n) = 1, F = F0, D(1) = 1/(pi a^2): f = F0 / (4 pi a^2)
    assert ct.shape(z, z)[0] == pytest.approx(0.3 / (4 * math.pi * ct.alpha**2), rel=1e-12)


@pytest.mark.parametrize("brdf", ALL[1:], ids=lambda b: b.name)
def test_energy_conservation(brdf: object) -> None:
    for theta in (0.0, 0.5, 1.0):
        wo = np.array([math.sin(theta), 0.0, math.cos(theta)])
        a = _albedo(brdf, wo)
        assert 0.2 < a <= 1.0 + 1e-3, (brdf.name, theta, a)  # never creates energy


def test_bad_inputs() -> None:
    ph = Phong()
    with pytest.raises(PrtError, match=r"\(N, 3\)"):
        ph.shape(np.zeros((4, 2)), np.zeros((4, 2)))
    with pytest.raises(PrtError, match="unit"):
        ph.shape(np.ones((4, 3)), _upper(4, 0))
    bad = _upper(4, 0)
    bad[1, 0] = np.nan
    with pytest.raises(PrtError, match="NaN"):
        ph.shape(bad, _upper(4, 0))
    with pytest.raises(PrtError, match="same shape"):
        ph.shape(_upper(4, 0), _upper(5, 0))
    with pytest.raises(PrtError, match="energy"):
        Phong(kd=0.7, ks=0.7)
    with pytest.raises(PrtError, match="roughness"):
        CookTorrance(roughness=0.0)
    with pytest.raises(PrtError, match="tint"):
        Lambert(tint=[1.0, -1.0, 0.0])
    with pytest.raises(PrtError, match="alpha"):
        Ward(alpha=5.0)

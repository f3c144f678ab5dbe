"""Directional / disk lights and the procedural sky vs scipy quadrature and pixel-quadrature projection."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import integrate, special

from prt_torch.errors import PrtError
from prt_torch.light.envmap import EnvMap, envmap_to_sh, latlong_directions
from prt_torch.light.sources import (
    DEFAULT_SUN,
    cap_zh,
    cie_clear_sky,
    directional_light_sh,
    sky_envmap,
    sky_sh,
)
from prt_torch.sh.basis import sh_basis


@pytest.mark.parametrize("beta", [0.05, 0.4, 1.2, math.pi])
def test_cap_zh_vs_scipy(beta: float) -> None:
    c = math.cos(beta)
    g = cap_zh(7, beta)
    for l in range(7):  # Funk-Hecke: g_l = int_c^1 P_l(t) dt / (1 - c) for a unit-power cap
        ref, _ = integrate.quad(lambda t, l=l: special.eval_legendre(l, t), c, 1.0, epsabs=1e-13)
        assert g[l] == pytest.approx(ref / (1 - c), abs=1e-10)


def test_disk_light_vs_rendered_map() -> None:
    d = np.array([0.3, -0.5, 0.6])
    d /= np.linalg.norm(d)
    beta = math.radians(25)
    color = np.array([2.0, 1.0, 0.5])
    dirs = latlong_directions(256, 512)
    inside = dirs @ d >= math.cos(beta)
    radiance = color / (2 * math.pi * (1 - math.cos(beta)))
    env = EnvMap((inside[..., None] * radiance).astype(np.float32), "latlong")
    got = directional_light_sh(d, color, 5, half_angle=beta)
    ref = envmap_to_sh(env, 5)
    np.testing.assert_allclose(got, ref, atol=0.01 * np.abs(ref).max())


def test_directional_is_the_limit_of_small_disks() -> None:
    d = np.array([0.0, 0.6, 0.8])
    a = directional_light_sh(d, 3.0, 6)
    np.testing.assert_allclose(a[:, 0], 3.0 * sh_basis(d, 6))
    b = directional_light_sh(d, 3.0, 6, half_angle=1e-3)
    np.testing.assert_allclose(a, b, rtol=1e-5)
    # irradiance on the facing surface from the order-6 SH: sum_lm A_l l_lm y_lm(d); by the addition theorem
    # sum_m y_lm(d)^2 = (2l+1)/(4 pi), so it equals E sum_l A_l (2l+1)/(4 pi) (R&H A_l: pi, 2pi/3, pi/4, 0, -pi/24, 0)
    from prt_torch.sh.zonal import clamped_cosine_zh, zh_to_sh

    cos_lobe = zh_to_sh(clamped_cosine_zh(6), d)
    a_l = [math.pi, 2 * math.pi / 3, math.pi / 4, 0.0, -math.pi / 24, 0.0]
    expected = 3.0 * sum(a * (2 * l + 1) / (4 * math.pi) for l, a in enumerate(a_l))
    assert float(cos_lobe @ a[:, 0]) == pytest.approx(expected, rel=1e-12)
    assert expected == pytest.approx(3.0, rel=0.05)  # close to E itself


def test_cie_sky_normalised_and_sun_separable() -> None:
    s = np.asarray(DEFAULT_SUN)
    assert cie_clear_sky(np.array([0.0, 0.0, 1.0]), s) == pytest.approx(1.0, rel=1e-12)
    assert cie_clear_sky(np.array([0.6, 0.0, -0.8]), s) == 0.0
    # brighter toward the sun than away from it at the same elevation
    toward = np.array([s[0], s[1], 0]) / np.hypot(s[0], s[1]) * 0.6 + np.array([0, 0, 0.8])
    away = np.array([-toward[0], -toward[1], 0.8])
    assert cie_clear_sky(toward, s) > 2 * cie_clear_sky(away, s)
    env = sky_envmap(s, height=64)
    assert np.allclose(env.image[40:], env.image[40:][0, 0])  # uniform ground below the horizon
    with_sun = sky_sh(4, s, height=64)
    no_sun = sky_sh(4, s, sun_color=0.0, height=64)
    np.testing.assert_allclose(with_sun - no_sun, directional_light_sh(s, (30.0, 28.0, 24.0), 4,
                                                                       half_angle=math.radians(0.265)), atol=1e-9)
    # the pixel quadrature has converged: 64 rows vs 256 rows
    np.testing.assert_allclose(no_sun, sky_sh(4, s, sun_color=0.0, height=256), atol=0.01 * np.abs(no_sun).max())


def test_bad_inputs() -> None:
    with pytest.raises(PrtError, match="unit"):
        directional_light_sh([1.0, 1.0, 0.0], 1.0, 3)
    with pytest.raises(PrtError, match="NaN"):
        directional_light_sh([0.0, 0.0, 1.0], [1.0, np.nan, 0.0], 3)
    with pytest.raises(PrtError, match="RGB"):
        directional_light_sh([0.0, 0.0, 1.0], [1.0, 1.0], 3)
    with pytest.raises(PrtError, match=r"shape \(3,\)"):
        directional_light_sh(np.eye(3), 1.0, 3)
    with pytest.raises(PrtError, match="half-angle"):
        directional_light_sh([0.0, 0.0, 1.0], 1.0, 3, half_angle=-0.1)
    with pytest.raises(PrtError, match="unsupported SH order"):
        directional_light_sh([0.0, 0.0, 1.0], 1.0, 0)
    with pytest.raises(PrtError, match="height"):
        sky_envmap(height=2)

"""Analytic light sources in SH: directional (and small-disk) lights and a procedural sun + sky.

All functions return lighting ``(C, 3)`` float64 RGB radiance coefficients (``C = order**2``) in the
world frame (z up), numpy only.

* A **directional light** of colour ``E`` (irradiance on a surface facing it, i.e. power per unit area)
  is the delta ``E delta(w, d)``; its coefficients are ``E y(d)`` (a ZH lobe with ``g_l = E``).
* A **disk light** (spherical cap of half-angle ``beta`` about ``d`` with uniform radiance
  ``E / Omega_cap``) has ZH band coefficients (Funk-Hecke, ``f_lm = g_l y_lm(d)``)
  ``g_l = 2 pi int h(t) P_l(t) dt = E (P_{l-1}(c) - P_{l+1}(c)) / ((2l+1)(1-c))``, ``c = cos beta``
  (``g_0 = E``); it tends to the directional light as ``beta -> 0``.
* The **sky** is the CIE standard clear-sky luminance distribution (Kittler 1998 / CIE S 011)
  coloured by a zenith tint, a uniform ground below the horizon, plus the sun as a disk light.
  It is rendered into a lat-long map and projected with exact pixel solid angles.
"""

from __future__ import annotations

import numpy as np
from numpy.polynomial import legendre

from prt_torch.errors import PrtError
from prt_torch.light.envmap import EnvMap, envmap_to_sh, latlong_directions
from prt_torch.sh.basis import band_of, check_directions, check_order, sh_basis


def _rgb(color: object, name: str) -> np.ndarray:
    c = np.asarray(color, dtype=np.float64)
    if c.ndim == 0:
        c = np.full(3, float(c))
    if c.shape != (3,):
        raise PrtError(f"{name} must be a scalar or an RGB triple, got shape {c.shape}")
    if not np.isfinite(c).all():
        raise PrtError(f"{name} contains NaN or Inf")
    return c


def _unit(direction: object, name: str) -> np.ndarray:
    d = np.asarray(direction, dtype=np.float64)
    check_directions(d, name, atol=1e-6)
    if d.shape != (3,):
        raise PrtError(f"{name} must be a single direction of shape (3,), got {d.shape}")
    return d / np.linalg.norm(d)


#: default sun direction: 60 degrees above the horizon, azimuth 30 degrees from +x toward +y (unit).
DEFAULT_SUN = (0.4330127018922193, 0.25, 0.8660254037844386)

#: the real sun's angular radius (half of its 0.53 degree diameter), radians: a disc of ``6.7e-5`` sr
SUN_HALF_ANGLE = float(np.radians(0.53 / 2))


def cap_zh(order: int, half_angle: float) -> np.ndarray:
    """ZH band coefficients ``g_l (n,)`` of a unit-power uniform spherical cap (``g_0 = 1``)."""
    check_order(order)
    if not (0.0 <= half_angle <= np.pi) or not np.isfinite(half_angle):
        raise PrtError(f"cap half-angle must be in [0, pi], got {half_angle}")
    c = float(np.cos(half_angle))
    if half_angle == 0.0 or 1.0 - c < 1e-12:
        return np.ones(order)
    p = np.array([legendre.legval(c, np.eye(order + 1)[l]) for l in range(order + 1)])  # P_0..P_order at c
    g = np.empty(order)
    g[0] = 1.0
    for l in range(1, order):
        g[l] = (p[l - 1] - p[l + 1]) / ((2 * l + 1) * (1.0 - c))
    return g


def directional_light_sh(direction: object, color: object, order: int, half_angle: float = 0.0) -> np.ndarray:
    """SH of a directional light (``half_angle = 0``) or a uniform disk light (cap) toward ``direction``.

    Args:
        direction: ``(3,)`` unit vector toward the light, world frame (z up).
        color: RGB (or scalar) power ``E``: irradiance delivered to a surface facing the light.
        order: SH order ``n``.
        half_angle: angular radius of the disk in radians (0 = delta light).

    Returns:
        ``(C, 3)`` float64 with ``l_lm = g_l y_lm(d) E``.
    """
    check_order(order)
    d = _unit(direction, "light direction")
    e = _rgb(color, "light color")
    g = cap_zh(order, half_angle)[band_of(order)]
    return (g * sh_basis(d, order))[:, None] * e[None, :]


def cie_clear_sky(dirs: np.ndarray, sun_direction: np.ndarray) -> np.ndarray:
    """Relative CIE clear-sky luminance at world directions ``(..., 3)`` (z up) -> ``(...)``, 1 at the zenith.

    ``L/Lz = f(gamma) phi(theta) / (f(theta_s) phi(0))`` with ``f(x) = 0.91 + 10 exp(-3x) + 0.45 cos^2 x``,
    ``phi(theta) = 1 - exp(-0.32 / cos theta)``; ``theta`` zenith angle of the view direction, ``gamma`` its
    angle to the sun, ``theta_s`` the sun's zenith angle. Zero below the horizon.
    """
    z = dirs[..., 2]
    cos_g = np.clip(dirs @ sun_direction, -1.0, 1.0)
    gamma = np.arccos(cos_g)
    theta_s = float(np.arccos(np.clip(sun_direction[2], -1.0, 1.0)))

    def f(x: np.ndarray | float) -> np.ndarray:
        return 0.91 + 10.0 * np.exp(-3.0 * np.asarray(x)) + 0.45 * np.cos(x) ** 2

    up = z > 1e-9
    phi = np.where(up, 1.0 - np.exp(-0.32 / np.where(up, z, 1.0)), 0.0)
    return f(gamma) * phi / (f(theta_s) * (1.0 - np.exp(-0.32)))


def sky_envmap(sun_direction: object = DEFAULT_SUN, sky_color: object = (0.35, 0.55, 1.0),
               ground_color: object = (0.25, 0.22, 0.2), height: int = 128) -> EnvMap:
    """Render the procedural sky (without the sun disk) into a ``2H x H`` lat-long :class:`EnvMap`."""
    if not isinstance(height, int) or height < 4:
        raise PrtError(f"sky map height must be an integer >= 4, got {height!r}")
    s = _unit(sun_direction, "sun direction")
    sky, ground = _rgb(sky_color, "sky color"), _rgb(ground_color, "ground color")
    d = latlong_directions(height, 2 * height)
    lum = cie_clear_sky(d, s)
    img = lum[..., None] * sky + (d[..., 2] <= 0)[..., None] * ground
    return EnvMap(img.astype(np.float32), "latlong", source="procedural sky")


def sky_sh(order: int, sun_direction: object = DEFAULT_SUN, sun_color: object = (30.0, 28.0, 24.0),
           sky_color: object = (0.35, 0.55, 1.0), ground_color: object = (0.25, 0.22, 0.2),
           sun_half_angle: float = SUN_HALF_ANGLE, height: int = 128) -> np.ndarray:
    """SH ``(C, 3)`` of a sun + clear sky + ground: CIE clear sky (projected by exact lat-long quadrature)
    plus the sun as a disk light of power ``sun_color`` (if the sun is above the horizon)."""
    check_order(order)
    s = _unit(sun_direction, "sun direction")
    out = envmap_to_sh(sky_envmap(s, sky_color, ground_color, height), order)
    if s[2] > 0:
        out = out + directional_light_sh(s, sun_color, order, sun_half_angle)
    return out

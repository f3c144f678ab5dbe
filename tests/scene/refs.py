"""Independent references for the scene tests: dense spherical quadrature of indicator functions, the
closed-form ZH of a spherical cap (scipy's Legendre polynomials), the sphere's diffuse form factor."""

from __future__ import annotations

import numpy as np
from scipy.special import eval_legendre

from prt_torch.sh.basis import sh_basis


def fibonacci_sphere(n: int) -> tuple[np.ndarray, float]:
    """``n`` near-uniform unit directions (spherical Fibonacci) and the equal weight ``4 pi / n``."""
    i = np.arange(n) + 0.5
    z = 1.0 - 2.0 * i / n
    phi = i * np.pi * (3.0 - np.sqrt(5.0))
    r = np.sqrt(1.0 - z * z)
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], -1), 4.0 * np.pi / n


def project_indicator(fn, order: int, n: int = 400_000) -> np.ndarray:
    """SH coefficients (C, ...) of ``fn(dirs (N, 3)) -> (N, ...)`` by dense equal-weight quadrature."""
    d, w = fibonacci_sphere(n)
    y = sh_basis(d, order)  # (N, C)
    vals = np.asarray(fn(d), dtype=np.float64)
    return w * np.tensordot(y, vals, axes=(0, 0))


def cap_sh(axis: np.ndarray, half_angle: np.ndarray, order: int) -> np.ndarray:
    """``(..., C)`` SH of the indicator of the cap of ``half_angle`` about unit ``axis (..., 3)``: ZH bands
    ``g_l = 2 pi int_{cos a}^1 P_l(t) dt = 2 pi (P_{l-1}(x) - P_{l+1}(x)) / (2l + 1)`` (``g_0 = 2 pi (1 - x)``)."""
    x = np.cos(np.asarray(half_angle, dtype=np.float64))[..., None]
    ls = np.arange(order)
    g = np.where(ls == 0, 2 * np.pi * (1 - x),
                 2 * np.pi * (eval_legendre(np.maximum(ls - 1, 0), x) - eval_legendre(ls + 1, x)) / (2 * ls + 1))
    band = np.concatenate([[l] * (2 * l + 1) for l in range(order)])
    return g[..., band] * sh_basis(np.asarray(axis, dtype=np.float64), order)


def sphere_blocked_irradiance_fraction(p: np.ndarray, center: np.ndarray, radius: float) -> np.ndarray:
    """Fraction of a uniform sky's irradiance at points ``p (N, 3)`` on a ``+z`` plane blocked by a sphere fully
    above their horizon: the sphere's form factor ``sin^2(a) cos(theta)`` (a: angular radius, theta: the centre's
    zenith angle)."""
    d = center[None] - p
    dist = np.linalg.norm(d, axis=-1)
    return (radius / dist) ** 2 * (d[:, 2] / dist)

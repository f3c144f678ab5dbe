"""Quadrature rules and direction sets on the sphere (numpy only).

* :func:`sphere_quadrature` — a rule exact for spherical polynomials up to a stated degree: scipy's
  Lebedev rule (``scipy.integrate.lebedev_rule``, degrees up to 131, ~1e-14 accurate) for the
  smallest tabulated degree ``>= degree``; above 131 a Gauss-Legendre (in ``z = cos theta``) x
  uniform-``phi`` product rule, exact to the requested degree.
* :func:`hemisphere_directions` / :func:`sphere_directions` — spherical-Fibonacci low-discrepancy
  point sets, uniform in solid angle (equal weights), for ray casting and candidate searches.
* :func:`random_rotations` (uniform on SO(3)) and :func:`rotations_about_z`.

Directions are unit ``(x, y, z)`` float64 vectors in the frame of the caller (z = polar axis, the
normal in a local vertex frame).
"""

from __future__ import annotations

import functools
import math

import numpy as np
from scipy.integrate import lebedev_rule
from scipy.spatial.transform import Rotation

from prt_torch.errors import PrtError
from prt_torch.shapes import check_shape

#: Degrees (algebraic exactness) tabulated by ``scipy.integrate.lebedev_rule``.
LEBEDEV_DEGREES = (3, 5, 7, 9, 11, 13, 15, 17, 19, 21, 23, 25, 27, 29, 31, 35,
                   41, 47, 53, 59, 65, 71, 77, 83, 89, 95, 101, 107, 113, 119, 125, 131)

#: Highest degree :func:`sphere_quadrature` accepts (a 1001 x 2002 product rule).
MAX_DEGREE = 2000

_GOLDEN = (math.sqrt(5.0) - 1.0) / 2.0  # fractional part of the golden ratio


def _check_count(n: int, name: str = "n") -> None:
    if not isinstance(n, int | np.integer) or isinstance(n, bool) or n < 1:
        raise PrtError(f"{name} must be a positive integer, got {n!r}")


def _check_seed(seed: int | None) -> None:
    if seed is not None and (not isinstance(seed, int | np.integer) or isinstance(seed, bool)):
        raise PrtError(f"seed must be an integer or None, got {seed!r}")


def gauss_product_rule(degree: int) -> tuple[np.ndarray, np.ndarray]:
    """Gauss-Legendre x uniform-phi rule exact for spherical polynomials of total ``degree``.

    ``degree//2 + 1`` Gauss-Legendre nodes in ``z`` times ``degree + 1`` equally spaced ``phi``.

    Returns:
        ``dirs (N, 3)`` float64 unit vectors and ``weights (N,)`` float64 summing to ``4 pi``.
    """
    if not isinstance(degree, int | np.integer) or isinstance(degree, bool) or not 0 <= degree <= MAX_DEGREE:
        raise PrtError(f"unsupported quadrature degree {degree!r}: expected an integer in 0..{MAX_DEGREE}")
    nt = degree // 2 + 1
    nphi = degree + 1
    z, wz = np.polynomial.legendre.leggauss(nt)
    phi = (np.arange(nphi) + 0.5) * (2 * math.pi / nphi)
    r = np.sqrt(np.clip(1 - z * z, 0, None))
    dirs = np.stack(
        [np.outer(r, np.cos(phi)), np.outer(r, np.sin(phi)), np.repeat(z[:, None], nphi, axis=1)], axis=-1
    ).reshape(-1, 3)
    w = np.repeat(wz * (2 * math.pi / nphi), nphi)
    return dirs, w


@functools.cache
def _sphere_quadrature(degree: int) -> tuple[np.ndarray, np.ndarray]:
    for d in LEBEDEV_DEGREES:
        if d >= degree:
            x, w = lebedev_rule(d)
            dirs = np.ascontiguousarray(np.asarray(x, dtype=np.float64).T)
            dirs /= np.linalg.norm(dirs, axis=-1, keepdims=True)
            w = np.asarray(w, dtype=np.float64)
            break
    else:
        dirs, w = gauss_product_rule(degree)
    dirs.setflags(write=False)
    w.setflags(write=False)
    return dirs, w


def sphere_quadrature(degree: int) -> tuple[np.ndarray, np.ndarray]:
    """A rule integrating every spherical polynomial of total degree ``<= degree`` exactly.

    Lebedev (smallest tabulated degree ``>= degree``, up to 131), else Gauss-Legendre x uniform-phi.
    To integrate products of two order-``n`` SH functions use ``degree = 2(n-1)``; of three,
    ``3(n-1)``. Results are cached and read-only.

    Args:
        degree: 0..2000.

    Returns:
        ``dirs (N, 3)`` float64 unit vectors, ``weights (N,)`` float64 (positive, sum ``4 pi``).
    """
    if not isinstance(degree, int | np.integer) or isinstance(degree, bool) or not 0 <= degree <= MAX_DEGREE:
        raise PrtError(f"unsupported quadrature degree {degree!r}: expected an integer in 0..{MAX_DEGREE}")
    return _sphere_quadrature(int(degree))


def _fibonacci(n: int, z_lo: float, seed: int | None) -> np.ndarray:
    i = np.arange(n, dtype=np.float64)
    if seed is None:
        u, phi0 = 0.0, 0.0
    else:
        rng = np.random.default_rng(seed)
        u, phi0 = float(rng.random()), float(rng.random()) * 2 * math.pi
    frac = np.mod((i + 0.5) / n + u, 1.0)  # Cranley-Patterson shift of the stratified z coordinate
    z = 1.0 - frac * (1.0 - z_lo)
    phi = 2 * math.pi * np.mod(i * _GOLDEN, 1.0) + phi0  # random rotation about z
    r = np.sqrt(np.clip(1 - z * z, 0, None))
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=-1)


def hemisphere_directions(n: int, seed: int | None = None) -> np.ndarray:
    """Spherical-Fibonacci directions uniform in solid angle on the upper hemisphere ``z >= 0``.

    Point ``i`` has ``z = 1 - (i + 1/2)/n`` and ``phi = 2 pi frac(i * 0.618...)``; each carries the
    weight ``2 pi / n``. With a ``seed``, the set is randomised (still low-discrepancy): a
    Cranley-Patterson shift of the ``z`` stratum offset and a random rotation about ``z``.

    Returns:
        ``(n, 3)`` float64 unit vectors.
    """
    _check_count(n)
    _check_seed(seed)
    return _fibonacci(int(n), 0.0, seed)


def sphere_directions(n: int, seed: int | None = None) -> np.ndarray:
    """Spherical-Fibonacci directions uniform in solid angle on the whole sphere (weight ``4 pi / n`` each).

    Same construction as :func:`hemisphere_directions` with ``z`` spanning ``[-1, 1]``.

    Returns:
        ``(n, 3)`` float64 unit vectors.
    """
    _check_count(n)
    _check_seed(seed)
    return _fibonacci(int(n), -1.0, seed)


def random_rotations(n: int, seed: int | None = None) -> np.ndarray:
    """``n`` rotation matrices drawn uniformly (Haar measure) from SO(3), ``(n, 3, 3)`` float64."""
    _check_count(n)
    _check_seed(seed)
    return Rotation.random(int(n), rng=np.random.default_rng(seed)).as_matrix().reshape(int(n), 3, 3)


def rotations_about_z(angles: np.ndarray) -> np.ndarray:
    """Right-handed rotations by ``angles`` (radians) about ``+z``: ``(n,)`` -> ``(n, 3, 3)`` float64."""
    a = np.asarray(angles, dtype=np.float64)
    check_shape(a, "n", name="angles")
    if not np.isfinite(a).all():
        raise PrtError("angles contain NaN or Inf")
    c, s = np.cos(a), np.sin(a)
    out = np.zeros((a.shape[0], 3, 3))
    out[:, 0, 0] = c
    out[:, 0, 1] = -s
    out[:, 1, 0] = s
    out[:, 1, 1] = c
    out[:, 2, 2] = 1.0
    return out

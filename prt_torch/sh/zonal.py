"""Zonal harmonics (ZH): axially symmetric functions, their band coefficients and rotation.

Convention (``docs/DESIGN.md``, seed 003 eq. 15, [SLS05] eq. 18): a function ``f(w) = h(s . w)``
symmetric about the unit axis ``s`` has band coefficients ``g_l`` (``l < n``) such that its SH
coefficients are::

    f_lm = g_l * y_lm(s)                      (no sqrt(4 pi / (2l+1)) factor inside g_l)

By the Funk-Hecke theorem ``g_l = 2 pi int_{-1}^{1} h(t) P_l(t) dt`` (``P_l`` Legendre), so for
the clamped cosine ``h(t) = max(t, 0)`` the ``g_l`` are exactly Ramamoorthi & Hanrahan's (2001)
``A_l`` (``pi, 2 pi/3, pi/4, 0, -pi/24, ...``) and convolution with ``h`` multiplies band ``l`` of any
SH function by ``g_l`` (irradiance: ``E_lm = A_l L_lm``).

The other common convention stores the axis-aligned coefficients ``z_l`` (the ``y_l0`` coefficient
of ``f`` when ``s = +z``): ``g_l = sqrt(4 pi / (2l+1)) z_l``, see :func:`zh_band_scale`,
:func:`zh_from_axial`, :func:`zh_to_axial`.

Functions take numpy arrays or torch tensors (torch is imported lazily, never for numpy input);
fixed coefficient tables (:func:`clamped_cosine_zh`, :func:`hemisphere_zh`, :func:`zh_project`,
:func:`zh_band_scale`) are float64 numpy arrays ``(n,)``.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import TYPE_CHECKING, Any, TypeVar

import numpy as np

from prt_torch.errors import PrtError
from prt_torch.sh.basis import (
    band_of,
    check_directions,
    check_float_array,
    check_order,
    is_torch,
    order_from_coeffs,
    sh_basis,
)
from prt_torch.shapes import check_shape

if TYPE_CHECKING:
    import torch

Array = TypeVar("Array", "np.ndarray", "torch.Tensor")


def _as_backend(table: np.ndarray, like: Any) -> Any:
    """``table`` (float64 numpy) converted to the backend, dtype and device of ``like``."""
    if is_torch(like):
        import torch

        return torch.as_tensor(table, dtype=like.dtype, device=like.device)
    return table.astype(like.dtype if np.issubdtype(like.dtype, np.floating) else np.float64, copy=False)


def zh_band_scale(order: int) -> np.ndarray:
    """``sqrt(4 pi / (2l+1))`` for ``l < order``, shape ``(n,)`` float64: ``g_l = scale_l * z_l``."""
    check_order(order)
    l = np.arange(order, dtype=np.float64)
    return np.sqrt(4 * math.pi / (2 * l + 1))


def zh_from_axial(z: Array) -> Array:
    """Axis-aligned ZH coefficients ``z (..., n)`` (``y_l0`` coefficients about ``+z``) -> ``g (..., n)``."""
    check_float_array(z, "axial ZH coefficients")
    check_shape(z, "... n", name="axial ZH coefficients")
    order = int(z.shape[-1])
    check_order(order)
    return z * _as_backend(zh_band_scale(order), z)


def zh_to_axial(g: Array) -> Array:
    """Inverse of :func:`zh_from_axial`: ``g (..., n)`` -> axis-aligned ``z (..., n)``."""
    check_float_array(g, "ZH coefficients")
    check_shape(g, "... n", name="ZH coefficients")
    order = int(g.shape[-1])
    check_order(order)
    return g / _as_backend(zh_band_scale(order), g)


def zh_to_sh(g: Array, axis: Array, check: bool = True) -> Array:
    """SH coefficients of ZH functions rotated to ``axis``: ``f_lm = g_l * y_lm(axis)``.

    This is also the rotation of a ZH lobe to a direction (``rotate_zh`` is an alias).

    Args:
        g: ``(..., n)`` band coefficients (``n`` = order, 1..16).
        axis: ``(..., 3)`` unit axes; batch dims broadcast against ``g``'s.
        check: validate inputs.

    Returns:
        ``(..., n*n)`` SH coefficients, in the backend of the inputs (both numpy or both torch).
    """
    if check:
        check_float_array(g, "ZH coefficients")
        check_shape(g, "... n", name="ZH coefficients")
        check_order(int(g.shape[-1]))
        check_directions(axis, "ZH axis")
        if is_torch(g) != is_torch(axis):
            raise PrtError("ZH coefficients and axis must be both numpy or both torch")
        try:
            np.broadcast_shapes(tuple(g.shape[:-1]), tuple(axis.shape[:-1]))
        except ValueError:
            raise PrtError(
                f"ZH coefficients {tuple(g.shape)} and axis {tuple(axis.shape)} batch shapes do not broadcast"
            ) from None
    order = int(g.shape[-1])
    y = sh_basis(axis, order, check=False)
    band = band_of(order)
    if is_torch(g):
        import torch

        gb = g[..., torch.as_tensor(band, device=g.device)]
    else:
        gb = g[..., band]
    return gb * y


rotate_zh = zh_to_sh


def lobes_to_sh(dirs: Array, coeffs: Array, check: bool = True) -> Array:
    """Sum of RGB ZH lighting lobes as SH: ``l = sum_k zh_to_sh(coeffs[k, :, c], dirs[k])``.

    Args:
        dirs: ``(..., K, 3)`` unit lobe axes.
        coeffs: ``(..., K, n, ch)`` band coefficients per lobe and channel (``ch`` = 3 for RGB).

    Returns:
        ``(..., n*n, ch)`` SH coefficients (coefficient axis before the channel axis, like lighting).
    """
    if check:
        dims = check_shape(coeffs, "... K n ch", name="lobe coeffs")
        check_shape(dirs, "... K _", name="lobe coeffs' directions", dims=dims)
    g = coeffs.swapaxes(-1, -2) if not is_torch(coeffs) else coeffs.transpose(-1, -2)  # (..., K, ch, n)
    f = zh_to_sh(g, dirs[..., :, None, :], check=check)  # (..., K, ch, C)
    f = f.sum(-3)  # (..., ch, C)
    return f.swapaxes(-1, -2) if not is_torch(f) else f.transpose(-1, -2)


def clamped_cosine_zh(order: int) -> np.ndarray:
    """Closed-form ZH coefficients of ``max(cos theta, 0)``: ``g_l = A_l`` (R&H 2001), ``(n,)`` float64.

    ``A_0 = pi``, ``A_1 = 2 pi/3``, odd ``l > 1``: 0, even ``l``:
    ``A_l = 2 pi (-1)^(l/2 - 1) / ((l+2)(l-1)) * l! / (2^l ((l/2)!)^2)``.
    """
    check_order(order)
    out = np.zeros(order, dtype=np.float64)
    for l in range(order):
        if l == 0:
            out[l] = math.pi
        elif l == 1:
            out[l] = 2 * math.pi / 3
        elif l % 2 == 0:
            h = l // 2
            out[l] = (
                2 * math.pi * (-1) ** (h - 1) / ((l + 2) * (l - 1))
                * math.factorial(l) / (2**l * math.factorial(h) ** 2)
            )
    return out


def _legendre_at_zero(l: int) -> float:
    if l % 2:
        return 0.0
    h = l // 2
    return (-1) ** h * math.factorial(l) / (2**l * math.factorial(h) ** 2)


def hemisphere_zh(order: int) -> np.ndarray:
    """Closed-form ZH coefficients of the upper-hemisphere indicator ``[cos theta >= 0]``, ``(n,)`` float64.

    ``g_l = 2 pi int_0^1 P_l = 2 pi (P_{l-1}(0) - P_{l+1}(0)) / (2l+1)`` (``l >= 1``), ``g_0 = 2 pi``;
    even ``l > 0`` vanish. An unoccluded vertex's visibility is ``zh_to_sh(hemisphere_zh(n), normal)``.
    """
    check_order(order)
    out = np.zeros(order, dtype=np.float64)
    out[0] = 2 * math.pi
    for l in range(1, order):
        out[l] = 2 * math.pi * (_legendre_at_zero(l - 1) - _legendre_at_zero(l + 1)) / (2 * l + 1)
    return out


def zh_project(
    fn_of_cos: Callable[[np.ndarray], np.ndarray],
    order: int,
    n_points: int = 64,
    split_at_horizon: bool = True,
) -> np.ndarray:
    """ZH coefficients ``g_l = 2 pi int_{-1}^{1} h(t) P_l(t) dt`` of ``f(w) = h(cos theta)``, ``(n,)`` float64.

    Gauss-Legendre quadrature in ``t = cos theta`` with ``n_points`` nodes on each of ``[-1, 0]``
    and ``[0, 1]`` (``split_at_horizon``), or on ``[-1, 1]`` at once. Exact when ``h`` is a polynomial
    of degree ``<= 2 n_points - order`` on each interval, so with the split a kink or jump at the
    horizon (the clamped cosine, the hemisphere indicator) costs no accuracy.

    Args:
        fn_of_cos: vectorised ``h``: float64 ``(N,)`` cosines -> ``(N,)`` values.
        order: number of bands ``n``.
    """
    check_order(order)
    if not isinstance(n_points, int) or n_points < 1:
        raise PrtError(f"n_points must be a positive integer, got {n_points!r}")
    x, w = np.polynomial.legendre.leggauss(n_points)
    if split_at_horizon:
        t = np.concatenate([(x - 1) / 2, (x + 1) / 2])
        wt = np.concatenate([w, w]) / 2
    else:
        t, wt = x, w
    h = np.asarray(fn_of_cos(t), dtype=np.float64)
    check_shape(h, t.shape, name="fn_of_cos values (one per cosine)")
    if not np.isfinite(h).all():
        raise PrtError("fn_of_cos returned NaN or Inf")
    p = np.polynomial.legendre.legvander(t, order - 1)  # (N, n): P_l(t)
    return 2 * math.pi * (p * (wt * h)[:, None]).sum(0)


def irradiance_sh(light: Array) -> Array:
    """Irradiance ``E(n) = int L(w) max(n . w, 0) dw`` as SH: ``E_lm = A_l L_lm`` (R&H 2001).

    Args:
        light: ``(C, ...)`` SH radiance coefficients, coefficient axis first (e.g. ``(C, 3)`` RGB),
            numpy or torch.

    Returns:
        ``(C, ...)`` SH coefficients of the (cosine-weighted, not divided by pi) irradiance; a uniform
        unit environment gives ``E = pi`` everywhere.
    """
    check_float_array(light, "SH lighting")
    check_shape(light, "C ...", name="SH lighting")
    try:
        order = order_from_coeffs(int(light.shape[0]))
    except PrtError:
        raise PrtError(f"SH lighting first dimension {light.shape[0]} is not a square number n*n") from None
    check_order(order)
    scale = clamped_cosine_zh(order)[band_of(order)]
    scale = scale.reshape((-1,) + (1,) * (light.ndim - 1))
    return light * _as_backend(scale, light)

"""SH projection of sampled spherical functions, and reconstruction from coefficients.

``project`` computes ``f_i = sum_n w_n f(d_n) y_i(d_n)`` (a quadrature of ``int f y_i dw``); with a
rule from :func:`prt_torch.sh.quadrature.sphere_quadrature` of degree ``>= deg(f) + order - 1`` it
is exact for band-limited ``f``. With equal weights ``4 pi / N`` (or ``2 pi / N`` on a hemisphere set)
it is the Monte-Carlo / low-discrepancy estimate used by the bake.

numpy arrays and torch tensors are both accepted (torch imported lazily; differentiable).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, TypeVar

import numpy as np

from prt_torch.errors import PrtError
from prt_torch.sh.basis import check_directions, check_float_array, check_order, is_torch, order_from_coeffs, sh_basis
from prt_torch.shapes import check_shape

if TYPE_CHECKING:
    import torch

Array = TypeVar("Array", "np.ndarray", "torch.Tensor")


def project(values: Array, dirs: Array, weights: Array, order: int, check: bool = True) -> Array:
    """SH coefficients of a function sampled at quadrature directions.

    Args:
        values: ``(N, ...)`` samples ``f(d_n)`` (any trailing channel dims, e.g. ``(N, 3)`` RGB).
        dirs: ``(N, 3)`` unit directions.
        weights: ``(N,)`` quadrature weights (solid angle per sample; sum ``4 pi`` on the sphere).
        order: number of bands ``n``; ``C = n*n``.
        check: validate inputs.

    Returns:
        ``(C, ...)`` coefficients ``sum_n w_n y_i(d_n) f(d_n)``, in the backend/dtype of ``values``
        (all three inputs must share a backend).
    """
    if check:
        check_order(order)
        check_float_array(values, "values")
        check_float_array(weights, "weights")
        check_directions(dirs, "projection directions")
        dims = check_shape(dirs, "N 3", name="projection directions")
        check_shape(values, "N ...", name="values", dims=dims)
        check_shape(weights, "N", name="weights", dims=dims)
        if len({is_torch(values), is_torch(dirs), is_torch(weights)}) != 1:
            raise PrtError("values, dirs and weights must be all numpy or all torch")
    y = sh_basis(dirs, order, check=False)  # (N, C)
    yw = (y * weights[:, None]).T  # (C, N)
    if is_torch(values):
        yw = yw.to(values.dtype)
    else:
        yw = yw.astype(np.result_type(values.dtype, yw.dtype), copy=False)
    flat = values.reshape(values.shape[0], -1)
    return (yw @ flat).reshape((yw.shape[0],) + tuple(values.shape[1:]))


def reconstruct(coeffs: Array, dirs: Array, check: bool = True) -> Array:
    """Evaluate SH expansions at directions: ``f(d_n) = sum_i c_i y_i(d_n)``.

    Args:
        coeffs: ``(..., C)`` coefficients, coefficient axis **last**.
        dirs: ``(N, 3)`` unit directions (same backend as ``coeffs``).

    Returns:
        ``(..., N)`` values. For coefficient-first data such as lighting ``(C, 3)`` use :func:`evaluate`.
    """
    if check:
        check_float_array(coeffs, "SH coefficients")
        check_shape(coeffs, "... C", name="SH coefficients")
        check_directions(dirs, "reconstruction directions")
        check_shape(dirs, "N 3", name="reconstruction directions")
        if is_torch(coeffs) != is_torch(dirs):
            raise PrtError("coeffs and dirs must be both numpy or both torch")
    order = order_from_coeffs(int(coeffs.shape[-1]))
    check_order(order)
    y = sh_basis(dirs, order, check=False)  # (N, C)
    y = y.to(coeffs.dtype) if is_torch(coeffs) else y
    return coeffs @ y.T


def evaluate(coeffs: Array, dirs: Array, check: bool = True) -> Array:
    """Inverse of :func:`project` in layout: ``coeffs (C, ...)`` -> values ``(N, ...)`` at ``dirs (N, 3)``."""
    if check:
        check_float_array(coeffs, "SH coefficients")
        check_shape(coeffs, "C ...", name="SH coefficients")
    c = coeffs.shape[0]
    flat = coeffs.reshape(c, -1)
    out = reconstruct(flat.T, dirs, check=check)  # (P, N)
    return out.T.reshape((dirs.shape[0],) + tuple(coeffs.shape[1:]))

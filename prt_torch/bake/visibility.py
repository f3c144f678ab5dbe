"""Local-frame SH visibility from hemisphere rays (docs/DESIGN.md, "Visibility").

``v_i = int V(s) y_i(s) ds`` over the whole sphere in the vertex frame, with ``V = 0`` below
the horizon and where the ray hits the mesh. Rays are the shared hemisphere set ``d_r`` (each of
solid angle ``2 pi / R``) rotated per vertex by ``phi_v`` about the normal
(:mod:`prt_torch.bake.directions`); the projection is ONE matmul of the ``(R, V)`` visibility
with the shared ``(C, R)`` basis table, which yields the coefficients of ``V`` in each vertex's
*rotated* frame, followed by the cheap per-vertex SH rotation about ``z`` back to the frame
``(t, b, n)``.
"""

from __future__ import annotations

import math
from functools import lru_cache

import numpy as np

from prt_torch.errors import PrtError
from prt_torch.exact import fixed_order_matmul
from prt_torch.sh.basis import check_order, sh_basis


@lru_cache(maxsize=16)
def _z_pairs(order: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Indices of the ``(l, +m)`` and ``(l, -m)`` coefficients, and ``m``, for all ``l < order, m > 0``."""
    pos, neg, ms = [], [], []
    for l in range(order):
        for m in range(1, l + 1):
            pos.append(l * (l + 1) + m)
            neg.append(l * (l + 1) - m)
            ms.append(m)
    return np.array(pos, dtype=np.intp), np.array(neg, dtype=np.intp), np.array(ms, dtype=np.float64)


def rotate_sh_z(coeffs: np.ndarray, phi: np.ndarray | float) -> np.ndarray:
    """Rotate real SH coefficients about the ``z`` axis.

    Returns the coefficients of ``g(u) = f(Rz(phi)^T u)``, i.e. ``f`` turned by ``+phi`` about
    ``z`` (``D(Rz(phi)) @ f`` in the convention of ``sh.rotation``). Only the ``(l, m), (l, -m)``
    pairs mix: with ``a`` the ``cos(m phi)`` coefficient (index ``+m``) and ``b`` the ``sin``
    one (index ``-m``), ``a' = a cos(m phi) - b sin(m phi)``, ``b' = a sin(m phi) + b cos(m phi)``.

    Args:
        coeffs: ``(..., C)`` with ``C = order**2``.
        phi: angles broadcastable to ``coeffs.shape[:-1]`` (radians).

    Returns:
        ``(..., C)`` in the dtype of ``coeffs``.
    """
    C = coeffs.shape[-1]
    order = int(round(math.sqrt(C)))
    if order * order != C:
        raise PrtError(f"{C} SH coefficients is not a square number n*n")
    pos, neg, ms = _z_pairs(order)
    out = coeffs.copy()
    if len(ms) == 0:
        return out
    ang = np.asarray(phi, dtype=np.float64)[..., None] * ms  # (..., P)
    c = np.cos(ang).astype(coeffs.dtype)
    s = np.sin(ang).astype(coeffs.dtype)
    a = coeffs[..., pos]
    b = coeffs[..., neg]
    out[..., pos] = a * c - b * s
    out[..., neg] = a * s + b * c
    return out


def projection_table(local_dirs: np.ndarray, order: int) -> np.ndarray:
    """``(C, R)`` float32: ``y_i(d_r) * 2 pi / R`` for hemisphere directions ``d_r`` uniform in solid angle."""
    check_order(order)
    R = local_dirs.shape[0]
    Y = sh_basis(np.asarray(local_dirs, dtype=np.float64), order)
    return np.ascontiguousarray((Y.T * (2.0 * math.pi / R)).astype(np.float32))


def project_visibility(visible: np.ndarray, table: np.ndarray, phi: np.ndarray) -> np.ndarray:
    """SH visibility of a block of vertices.

    Args:
        visible: ``(R, V)`` float32, 1 where the ray of vertex ``v`` along ``Rz(phi_v) d_r`` escapes.
        table: ``(C, R)`` from :func:`projection_table`.
        phi: ``(V,)`` per-vertex rotation angles.

    Returns:
        ``(V, C)`` float32 coefficients in each vertex frame ``(t, b, n)``.
    """
    # (V, C): coefficients of f'(d) = V(Rz(phi) d); a fixed-order sum over the rays: the bake is bit-exact
    rotated = fixed_order_matmul(table, visible).T
    return rotate_sh_z(np.ascontiguousarray(rotated), phi)

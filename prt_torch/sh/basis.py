"""Real spherical harmonics: the basis every other module projects onto.

Convention (see ``docs/DESIGN.md``):

* real SH, orthonormal on the unit sphere: ``int y_i y_j dw = delta_ij``;
* index ``i = l*(l+1) + m`` for band ``l >= 0`` and ``-l <= m <= l``;
* "order n" means bands ``l < n``, i.e. ``C = n*n`` coefficients;
* **no Condon-Shortley phase**: band 1 is ``sqrt(3/(4 pi)) * (y, z, x)`` in index order, as in
  Ramamoorthi & Hanrahan (2001), whose irradiance constants then apply directly;
* directions are unit vectors ``(x, y, z)`` with ``z`` the polar axis
  (``z = cos(theta)``, ``x + i y = sin(theta) e^{i phi}``).

Formally, with ``P_l^m`` the associated Legendre function *without* the ``(-1)^m`` phase and
``K_lm = sqrt((2l+1)/(4 pi) (l-m)!/(l+m)!)``::

    y_{l,0}  = K_l0 P_l^0(cos theta)
    y_{l,m}  = sqrt(2) K_lm cos(m phi)   P_l^m(cos theta)      m > 0
    y_{l,-m} = sqrt(2) K_lm sin(m phi)   P_l^m(cos theta)      m > 0

Evaluation is polynomial in ``(x, y, z)`` (no trigonometry): ``sin^m(theta) e^{i m phi} =
(x + i y)^m`` and ``P_l^m(z) = sin^m(theta) Q_l^m(z)`` with ``Q`` from the usual three-term
recurrence.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any, TypeVar

import numpy as np

from prt_torch.errors import PrtError
from prt_torch.shapes import check_shape

if TYPE_CHECKING:  # torch is imported lazily: the run-time player evaluates SH with numpy alone
    import torch

Array = TypeVar("Array", "np.ndarray", "torch.Tensor")

#: Highest order (number of bands) :func:`sh_basis` accepts.
MAX_ORDER = 16


def num_coeffs(order: int) -> int:
    """Number of coefficients ``n*n`` of an order-``n`` expansion (bands ``l < n``)."""
    check_order(order)
    return order * order


def sh_index(l: int, m: int) -> int:
    """Flat index ``l*(l+1) + m`` of band ``l``, degree ``m``."""
    if l < 0 or abs(m) > l:
        raise PrtError(f"invalid SH index l={l}, m={m}: need l >= 0 and |m| <= l")
    return l * (l + 1) + m


def band_of(order: int) -> np.ndarray:
    """Band ``l`` of every flat index, shape ``(order**2,)`` int64 (numpy)."""
    check_order(order)
    return np.repeat(np.arange(order), 2 * np.arange(order) + 1)


def is_torch(a: Any) -> bool:
    return type(a).__module__.startswith("torch")


def check_float_array(a: Any, name: str, finite: bool = True) -> np.ndarray:
    """Validate a floating-point numpy array or torch tensor (finite unless ``finite=False``).

    Returns a numpy view (a CPU copy for torch input) for further checks; raises :class:`PrtError`.
    """
    if not (isinstance(a, np.ndarray) or is_torch(a)):
        raise PrtError(f"{name} must be a numpy array or torch tensor, got {type(a).__name__}")
    arr = a.detach().cpu().numpy() if is_torch(a) else a
    if not np.issubdtype(arr.dtype, np.floating):
        raise PrtError(f"{name} must be floating point, got {a.dtype}")
    if finite and not np.isfinite(arr).all():
        raise PrtError(f"{name} contain NaN or Inf")
    return arr


def order_from_coeffs(num: int) -> int:
    """Inverse of :func:`num_coeffs`; raises :class:`PrtError` if ``num`` is not a square."""
    n = int(round(math.sqrt(num)))
    if n * n != num or n < 1:
        raise PrtError(f"{num} SH coefficients is not a square number n*n")
    return n


def check_order(order: int, max_order: int = MAX_ORDER) -> None:
    """Raise :class:`PrtError` unless ``1 <= order <= max_order``."""
    if not isinstance(order, int) or isinstance(order, bool) or not 1 <= order <= max_order:
        raise PrtError(f"unsupported SH order {order!r}: expected an integer in 1..{max_order}")


def check_directions(dirs: Any, name: str = "directions", atol: float | None = None) -> None:
    """Validate ``(..., 3)`` finite unit vectors (numpy or torch); raises :class:`PrtError`.

    The unit-length tolerance is 1e-3 for 32-bit (and narrower) floats, 1e-8 for float64.
    """
    a = check_float_array(dirs, name, finite=False)
    check_shape(dirs, "... 3", name=name)
    if a.size == 0:
        return
    if not np.isfinite(a).all():
        raise PrtError(f"{name} contain NaN or Inf")
    tol = atol if atol is not None else (1e-8 if a.dtype == np.float64 else 1e-3)
    err = float(np.abs(np.linalg.norm(a.astype(np.float64), axis=-1) - 1).max())
    if err > tol:
        raise PrtError(f"{name} must be unit vectors (max | |d| - 1 | = {err:.3g} > {tol:g})")


def norm_consts(order: int) -> list[list[float]]:
    """``K_lm`` (times sqrt(2) for m > 0), computed in float64 with lgamma for stability."""
    out = []
    for l in range(order):
        row = []
        for m in range(l + 1):
            k = math.sqrt((2 * l + 1) / (4 * math.pi) * math.exp(math.lgamma(l - m + 1) - math.lgamma(l + m + 1)))
            row.append(k * (math.sqrt(2.0) if m > 0 else 1.0))
        out.append(row)
    return out


def sh_basis(dirs: Array, order: int, check: bool = True) -> Array:
    """Evaluate all real SH of bands ``l < order`` at unit directions.

    Works on numpy arrays and torch tensors alike (same code path; torch is never imported
    for numpy input), and is differentiable under torch autograd.

    Args:
        dirs: ``(..., 3)`` unit vectors, float32 or float64, numpy or torch.
        order: number of bands ``n`` (1..16).
        check: validate shape, finiteness and unit length (skip in hot loops that already did).

    Returns:
        ``(..., n*n)`` basis values in the dtype (and on the device) of ``dirs``.
    """
    check_order(order)
    if check:
        check_directions(dirs)
    x, y, z = dirs[..., 0], dirs[..., 1], dirs[..., 2]
    cols: list[Any] = [None] * (order * order)
    K = norm_consts(order)
    # c_m + i s_m = (x + i y)^m
    c = [x * 0 + 1]
    s = [x * 0]
    for _m in range(1, order):
        c.append(c[-1] * x - s[-1] * y)
        s.append(s[-1] * x + c[-2] * y)
    for m in range(order):
        # Q_m^m = (2m-1)!!  (no Condon-Shortley phase)
        qmm = float(math.prod(range(1, 2 * m, 2))) if m > 0 else 1.0
        q_prev2 = None
        q_prev = z * 0 + qmm
        for l in range(m, order):
            if l == m:
                q = q_prev
            elif l == m + 1:
                q = z * (2 * m + 1) * qmm
            else:
                q = ((2 * l - 1) * z * q_prev - (l + m - 1) * q_prev2) / (l - m)
            if l > m:
                q_prev2, q_prev = q_prev, q
            k = K[l][m]
            if m == 0:
                cols[l * (l + 1)] = k * q
            else:
                cols[l * (l + 1) + m] = k * q * c[m]
                cols[l * (l + 1) - m] = k * q * s[m]
    if is_torch(dirs):
        import torch

        return torch.stack(cols, dim=-1)
    return np.stack(cols, axis=-1)

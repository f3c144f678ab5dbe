"""SH triple products: the real Gaunt tensor and SH product matrices.

The real triple-product (Gaunt) tensor of order ``n`` (bands ``l < n``, ``C = n*n``) is::

    Gamma_ijk = int_S2 y_i(w) y_j(w) y_k(w) dw        i, j, k < C

in this project's real SH convention (``prt_torch.sh.basis``: orthonormal, index
``i = l*(l+1) + m``, no Condon-Shortley phase). It is symmetric in ``(i, j, k)`` and sparse:
non-zero only when the bands satisfy the triangle inequality with ``l_i + l_j + l_k`` even (and the
real-SH selection rule on ``|m|``). ``Gamma_000 = 1 / (2 sqrt(pi))``.

The projection of the product of two order-``n`` functions back onto order ``n`` is
``(a x b)_i = sum_jk Gamma_ijk a_j b_k = (M(a) b)_i`` with the *product matrix*
``M(a)_ij = sum_k a_k Gamma_ijk`` (seed 003, [RWS06]); ``M(a)`` is symmetric.

**Computation.** The integrand is a spherical polynomial of degree ``3(n-1)``, so a
Gauss-Legendre (in ``cos theta``) x uniform-``phi`` product rule with ``3(n-1)//2 + 1`` x
``3(n-1) + 1`` nodes integrates it exactly; in float64 the result matches the Wigner-3j based
``sympy.physics.wigner.real_gaunt`` to ~1e-15 (tested to 1e-12). Entries below 1e-13 (round-off
of entries that are exactly zero) are dropped. Results are cached per order.

**Sign conversion to sympy** (``sympy.physics.wigner.real_gaunt``; derived and tested in
``tests/sh/test_product.py``). sympy defines its real SH through the unitary map ``U`` of its
docstring applied to the complex ``Y_l^m`` *with* the Condon-Shortley phase:
``Z_l^mu = (Y_l^mu + (-1)^mu Y_l^-mu)/sqrt(2) = sqrt(2) Re Y_l^mu`` for ``mu > 0`` and
``Z_l^mu = i((-1)^mu Y_l^mu - Y_l^|mu|)/sqrt(2) = sqrt(2) Im Y_l^|mu|`` for ``mu < 0``. Since
``Y_l^m = (-1)^m N_lm P_l^m(cos theta) e^{i m phi}`` (``P`` without the phase), this gives
``Z_l^mu = (-1)^mu y_{l,mu}``: same ``m < 0 -> sin`` ordering and index as ours, and a per-``(l, m)``
sign ``s_lm = (-1)^m``. Hence ``real_gaunt(l1,l2,l3,m1,m2,m3) = s1 s2 s3 Gamma[(l1,m1),(l2,m2),(l3,m3)]``.
The product ``s1 s2 s3 = (-1)^(|m1|+|m2|+|m3|)`` is ``+1`` on every non-zero entry (the real-SH
selection rule needs ``|m3| = |m1| + |m2|`` or ``||m1| - |m2||``, so the ``|m|`` sum is even): the
tensors agree entry by entry. (sympy's ``Znm`` function itself differs again: it has
``-y_{l,m}`` for ``m < 0``; do not use it as the reference.)
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, TypeVar

import numpy as np

from prt_torch.conventions import BELOW_HORIZON
from prt_torch.errors import PrtError
from prt_torch.sh.basis import band_of, check_float_array, check_order, is_torch, order_from_coeffs, sh_basis
from prt_torch.sh.quadrature import gauss_product_rule
from prt_torch.shapes import check_shape

if TYPE_CHECKING:
    import torch

Array = TypeVar("Array", "np.ndarray", "torch.Tensor")

#: Highest order :func:`gaunt_tensor` (and the product functions) accept.
MAX_PRODUCT_ORDER = 8

_DROP_BELOW = 1e-13


@dataclass(frozen=True)
class GauntTensor:
    """Sparse real Gaunt tensor ``Gamma (C, C, C)`` in COO form, float64.

    Attributes:
        indices: ``(nnz, 3)`` int64 ``(i, j, k)`` of every non-zero entry (all permutations stored).
        values: ``(nnz,)`` float64 ``Gamma_ijk``.
        order: number of bands ``n``; ``C = n*n``.
    """

    indices: np.ndarray
    values: np.ndarray
    order: int

    @property
    def num_coeffs(self) -> int:
        """``C = order**2``."""
        return self.order * self.order

    @property
    def nnz(self) -> int:
        """Number of stored non-zeros."""
        return int(self.values.shape[0])

    def dense(self) -> np.ndarray:
        """Dense ``(C, C, C)`` float64 copy."""
        return dense_gaunt(self.order).copy()

    def torch(self, dtype: Any = None, device: Any = None, sparse: bool = False) -> torch.Tensor:
        """As a torch tensor ``(C, C, C)``: dense by default, a coalesced sparse COO tensor if ``sparse``.

        ``dtype`` defaults to ``torch.float64``.
        """
        import torch

        dtype = torch.float64 if dtype is None else dtype
        if sparse:
            idx = torch.from_numpy(self.indices.T.copy())
            val = torch.from_numpy(self.values.copy()).to(dtype)
            c = self.num_coeffs
            return torch.sparse_coo_tensor(idx, val, (c, c, c), device=device, check_invariants=True).coalesce()
        return torch.from_numpy(self.dense()).to(dtype=dtype, device=device)


def _check_product_order(order: int) -> None:
    check_order(order, MAX_PRODUCT_ORDER)


@functools.cache
def dense_gaunt(order: int) -> np.ndarray:
    _check_product_order(order)
    dirs, w = gauss_product_rule(3 * (order - 1))
    y = sh_basis(dirs, order, check=False)  # (N, C)
    g = np.einsum("ni,nj,nk->ijk", y * w[:, None], y, y, optimize=True)
    c = order * order
    srt = np.sort(np.indices((c, c, c)).reshape(3, -1), axis=0)
    g = g[srt[0], srt[1], srt[2]].reshape(c, c, c)  # exactly symmetric: every entry from its sorted (i<=j<=k)
    # exact zeros: selection rules (triangle + parity) plus round-off threshold
    band = band_of(order)
    li, lj, lk = np.meshgrid(band, band, band, indexing="ij")
    allowed = (lk <= li + lj) & (lk >= np.abs(li - lj)) & ((li + lj + lk) % 2 == 0)
    g[~allowed | (np.abs(g) < _DROP_BELOW)] = 0.0
    g.setflags(write=False)
    return g


@functools.cache
def gaunt_tensor(order: int) -> GauntTensor:
    """Real SH triple-product tensor ``Gamma_ijk = int y_i y_j y_k dw`` for ``i, j, k < order**2``.

    Args:
        order: number of bands ``n`` in 1..8 (``C = n*n``).

    Returns:
        :class:`GauntTensor` (sparse COO, float64, exact to ~1e-15), cached per order. Symmetric in
        ``(i, j, k)``; ``Gamma_000 = 1/(2 sqrt(pi))``.
    """
    g = dense_gaunt(order)
    idx = np.argwhere(g != 0).astype(np.int64)
    vals = g[idx[:, 0], idx[:, 1], idx[:, 2]].astype(np.float64)
    idx.setflags(write=False)
    vals.setflags(write=False)
    return GauntTensor(indices=idx, values=vals, order=order)


def _check_coeffs(a: Any, name: str) -> int:
    """Validate ``(..., C)`` finite float coefficients (numpy or torch); return the order."""
    arr = check_float_array(a, name, finite=False)
    check_shape(a, "... C", name=name)
    try:
        order = order_from_coeffs(int(a.shape[-1]))
    except PrtError:
        raise PrtError(f"{name} last dimension {a.shape[-1]} is not a square number of SH coefficients") from None
    if order > MAX_PRODUCT_ORDER:
        raise PrtError(f"unsupported SH order {order} for {name}: SH products support orders 1..{MAX_PRODUCT_ORDER}")
    if not np.isfinite(arr).all():
        raise PrtError(f"{name} contain NaN or Inf")
    return order


def _gaunt_like(order: int, like: Any) -> Any:
    """Dense Gamma as ``(C, C*C)`` with rows ``k`` and columns ``(i, j)``, in ``like``'s backend/dtype."""
    g = dense_gaunt(order)
    c = order * order
    mat = np.ascontiguousarray(g.transpose(2, 0, 1).reshape(c, c * c))
    if is_torch(like):
        import torch

        return torch.from_numpy(mat).to(dtype=like.dtype, device=like.device)
    return mat.astype(like.dtype, copy=False)


def product_matrix(a: Array, check: bool = True) -> Array:
    """SH product matrices ``M(a)_ij = sum_k a_k Gamma_ijk``.

    ``M(a) @ b`` is the order-``n`` projection of the product of the functions with coefficients
    ``a`` and ``b``; ``M(a)`` is symmetric.

    Args:
        a: ``(..., C)`` coefficients, ``C = n*n`` with ``n`` in 1..8, numpy or torch (any float dtype;
            differentiable under torch autograd).
        check: validate shape and finiteness (skip in hot loops that already did).

    Returns:
        ``(..., C, C)`` in the backend, dtype and device of ``a``.
    """
    order = _check_coeffs(a, "SH coefficients") if check else order_from_coeffs(int(a.shape[-1]))
    c = order * order
    m = a @ _gaunt_like(order, a)  # (..., C*C)
    return m.reshape(*a.shape[:-1], c, c)


def sh_product(a: Array, b: Array, check: bool = True) -> Array:
    """Projected SH product ``(a x b)_i = sum_jk Gamma_ijk a_j b_k`` (same order as the inputs).

    Args:
        a, b: ``(..., C)`` coefficients of the same order (batch dims broadcast), numpy or torch.
        check: validate shapes and finiteness.

    Returns:
        ``(..., C)`` coefficients of the product function projected back onto order ``n``.
    """
    if check:
        na = _check_coeffs(a, "SH coefficients a")
        nb = _check_coeffs(b, "SH coefficients b")
        if na != nb:
            raise PrtError(f"sh_product needs equal orders, got {na} and {nb}")
        if is_torch(a) != is_torch(b):
            raise PrtError("sh_product needs a and b both numpy or both torch")
    m = product_matrix(a, check=False)
    return (m @ b[..., :, None])[..., 0]


@functools.cache
def hemisphere_product(order: int) -> np.ndarray:
    """``(C, C)`` float64 product matrix ``P_H`` of the upper-hemisphere indicator about local ``+z`` (symmetric,
    read-only): ``P_H v`` is the SH of ``H * v``."""
    from prt_torch.sh.zonal import hemisphere_zh, zh_to_sh

    out = product_matrix(zh_to_sh(hemisphere_zh(order), np.array([0.0, 0.0, 1.0])))
    out.flags.writeable = False
    return out


def mask_below_horizon(v: np.ndarray, order: int, below_horizon: str | None) -> np.ndarray:
    """``(..., C)`` float64: whole-sphere local-frame visibility ``v`` in a below-horizon convention (seed 003
    eq. 1): ``"zero"``: ``H v``; ``"one"``: ``1 - H (1 - v)`` (only upper-hemisphere occlusion counts); ``None``:
    ``v``. The numpy twin of :class:`prt_torch.shexp.ShexpVisibility`'s last step (the same ``P_H``)."""
    if below_horizon is not None and below_horizon not in BELOW_HORIZON:
        raise PrtError(f"below_horizon must be None, 'zero' or 'one', got {below_horizon!r}")
    v = np.asarray(v, dtype=np.float64)
    if below_horizon is None:
        return v
    p_h = hemisphere_product(order)
    if below_horizon == "zero":
        return v @ p_h
    one = np.zeros(order * order)
    one[0] = np.sqrt(4.0 * np.pi)
    return one - (one - v) @ p_h

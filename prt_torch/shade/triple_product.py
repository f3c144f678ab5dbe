"""The projected SH product ``(a x b)_k = sum_ij Gamma_ijk a_i b_j`` in two ONNX-friendly dense forms
(no ``torch.sparse`` in the forward path):

* **outer + GEMM** (:func:`outer_product_sh`): ``(a (x) b).reshape(C*C) @ Gamma.reshape(C*C, C)``: ``C^3``
  multiply-adds per product but one BLAS GEMM over all vertices - the fastest on CPU in ``prt bench shade``;
* **gather** (:func:`gather_product`): only the Gaunt non-zeros (see below), ``C P`` multiply-adds, but
  advanced indexing is slow in PyTorch on CPU (measured ~10x slower than the GEMM form at order 4).

The non-zeros of the real Gaunt tensor ``Gamma_ijk`` (:func:`prt_torch.sh.product.gaunt_tensor`) are
grouped by output index ``k`` and padded to ``P`` = the largest group (28 at order 4, 353 non-zeros in
all): ``I, J (C, P)`` int64 and ``G (C, P)`` values (0 in the padding). Then

    (a x b)_k = sum_p G[k, p] a[..., I[k, p]] b[..., J[k, p]]

costs ``C P`` multiply-adds per product (448 at order 4) instead of ``C^3`` dense or ``C^2`` per
product-matrix application; it is three ``Gather``/``Mul``/``ReduceSum`` ops in ONNX.
"""

from __future__ import annotations

import functools
from typing import Any

import numpy as np
import torch

from prt_torch.sh.basis import check_order
from prt_torch.sh.product import MAX_PRODUCT_ORDER, gaunt_tensor


@functools.cache
def gaunt_gather_tables(order: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Padded per-output gather tables ``(I, J, G)``, each ``(C, P)`` (int64, int64, float64)."""
    check_order(order, MAX_PRODUCT_ORDER)
    g = gaunt_tensor(order)
    c = order * order
    k = g.indices[:, 2]
    counts = np.bincount(k, minlength=c)
    p = int(counts.max())
    I = np.zeros((c, p), dtype=np.int64)
    J = np.zeros((c, p), dtype=np.int64)
    G = np.zeros((c, p), dtype=np.float64)
    order_idx = np.argsort(k, kind="stable")
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    slot = np.arange(len(k)) - starts[k[order_idx]]
    I[k[order_idx], slot] = g.indices[order_idx, 0]
    J[k[order_idx], slot] = g.indices[order_idx, 1]
    G[k[order_idx], slot] = g.values[order_idx]
    for a in (I, J, G):
        a.setflags(write=False)
    return I, J, G


def gaunt_gather_tensors(order: int, dtype: Any = torch.float32, device: Any = None) -> tuple[torch.Tensor, ...]:
    """:func:`gaunt_gather_tables` as torch tensors ``(I, J, G)`` (``G`` in ``dtype``)."""
    I, J, G = gaunt_gather_tables(order)
    return (torch.from_numpy(I.copy()).to(device), torch.from_numpy(J.copy()).to(device),
            torch.from_numpy(G.copy()).to(dtype=dtype, device=device))


@functools.cache
def gaunt_flat(order: int) -> np.ndarray:
    """Dense Gaunt tensor reshaped to ``(C*C, C)`` float64: row ``i*C + j``, column ``k``."""
    check_order(order, MAX_PRODUCT_ORDER)
    c = order * order
    out = gaunt_tensor(order).dense().reshape(c * c, c)
    out.setflags(write=False)
    return out


def outer_product_sh(a: torch.Tensor, b: torch.Tensor, gamma_flat: torch.Tensor) -> torch.Tensor:
    """Projected SH product of ``a, b (..., C)`` (same batch shape) -> ``(..., C)`` via the outer product and
    one GEMM with ``gamma_flat (C*C, C)`` (:func:`gaunt_flat`). No input validation (hot path)."""
    c = a.shape[-1]
    outer = (a.unsqueeze(-1) * b.unsqueeze(-2)).reshape(*a.shape[:-1], c * c)
    return outer @ gamma_flat


def gather_product(a: torch.Tensor, b: torch.Tensor, I: torch.Tensor, J: torch.Tensor, G: torch.Tensor) -> torch.Tensor:
    """Projected SH product ``(a x b)_k = sum_ij Gamma_ijk a_i b_j`` of ``a, b (..., C)`` -> ``(..., C)``.

    Batch dimensions broadcast; no input validation (hot path).
    """
    return (a[..., I] * b[..., J] * G).sum(-1)

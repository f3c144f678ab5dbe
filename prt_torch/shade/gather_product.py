"""The SH triple product as dense gathers: ONNX-friendly, no ``torch.sparse`` in the forward path.

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


def gather_product(a: torch.Tensor, b: torch.Tensor, I: torch.Tensor, J: torch.Tensor, G: torch.Tensor) -> torch.Tensor:
    """Projected SH product ``(a x b)_k = sum_ij Gamma_ijk a_i b_j`` of ``a, b (..., C)`` -> ``(..., C)``.

    Batch dimensions broadcast; no input validation (hot path).
    """
    return (a[..., I] * b[..., J] * G).sum(-1)

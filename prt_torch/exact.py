"""Fixed-order arithmetic: results with the same bits on every machine (docs/DESIGN.md, "Determinism").

BLAS libraries (OpenBLAS in numpy, MKL in torch, MLAS in onnxruntime) choose their kernels - and with them the
order of every sum - by CPU, by ``OPENBLAS_CORETYPE`` and by thread count, so one ``np.matmul`` can differ by an
ulp between two machines. What must be bit-exact across machines (the bake) uses these instead:
:func:`small_matmul` (products of joint transforms of elementwise numpy operations, each correctly rounded) and
:func:`fixed_order_matmul` (numba, a sequential sum over the inner axis, no fused multiply-add, no fast-math).
"""

from __future__ import annotations

import numba
import numpy as np


def small_matmul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``a @ b`` for stacks of small float64 matrices ``(..., n, k) @ (..., k, m)`` (broadcast; joint transforms,
    rotations), the same bits on every machine.

    Each entry is ``((a_i0 b_0j + a_i1 b_1j) + a_i2 b_2j) + ...``: elementwise numpy products and sums, each
    correctly rounded (IEEE 754), in that order - no BLAS kernel, no fused multiply-add.
    """
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    if a.ndim < 2 or b.ndim < 2 or a.shape[-1] != b.shape[-2]:
        raise ValueError(f"small_matmul: shapes {a.shape} and {b.shape} do not chain")
    out = a[..., :, 0:1] * b[..., 0:1, :]
    for j in range(1, a.shape[-1]):
        out = out + a[..., :, j:j + 1] * b[..., j:j + 1, :]
    return out


@numba.njit(cache=True, nogil=True)
def _matmul_rows(a: np.ndarray, b: np.ndarray, out: np.ndarray) -> None:  # pragma: no cover - compiled
    n_m, n_k = a.shape
    n_n = b.shape[1]
    for m in range(n_m):
        for n in range(n_n):
            out[m, n] = 0.0
        for k in range(n_k):
            s = a[m, k]
            for n in range(n_n):
                out[m, n] += s * b[k, n]


def fixed_order_matmul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``a @ b`` for ``a (..., M, K)``, ``b (K, N)`` float32, the same bits on every machine and thread count.

    ``out[..., m, n] = (((a_m0 b_0n) + a_m1 b_1n) + ...) + a_m(K-1) b_(K-1)n`` in float32, each product and sum
    rounded (numba without fast-math: no reassociation, no fused multiply-add); vectorised over ``n`` only, so
    every lane keeps that order. ~1-2 GFLOP/s on one core: for the bake's skinning and SH projection, whose
    cost is the ray casting.
    """
    a = np.ascontiguousarray(a, dtype=np.float32)
    b = np.ascontiguousarray(b, dtype=np.float32)
    if a.ndim < 2 or b.ndim != 2 or a.shape[-1] != b.shape[0]:
        raise ValueError(f"fixed_order_matmul: shapes {a.shape} and {b.shape} do not chain")
    lead = a.shape[:-2]
    flat = a.reshape(-1, a.shape[-1]) if lead else a
    out = np.empty((flat.shape[0], b.shape[1]), np.float32)
    _matmul_rows(flat, b, out)
    return out.reshape(*lead, a.shape[-2], b.shape[1])

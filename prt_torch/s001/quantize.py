"""16-bit affine quantization of coefficient tables (seed 001 section 6: "we quantize each PCA coefficient
down to 16 bits").

``quantize16(x)`` maps every column of ``x (N, M)`` (optionally every column within each row group, e.g.
each PCA cluster) to ``uint16`` codes ``q = round((x - offset) / scale)`` with ``offset = min`` and
``scale = (max - min) / 65535`` of that column (group), so ``dequantize16`` returns
``offset + q * scale`` and the error of every entry is at most ``scale / 2`` (plus float32 rounding of
``scale``/``offset``). A constant column gets ``scale = 0`` and is reproduced exactly.
Bytes: codes ``2 N M`` + ``scale``/``offset`` ``2 x 4 G M`` (float32) against ``4 N M`` for raw float32.
"""

from __future__ import annotations

import numpy as np

from prt_torch.errors import check
from prt_torch.shapes import check_shape

LEVELS = 65535


def _groups(groups: np.ndarray | None, n: int, name: str) -> tuple[np.ndarray, int]:
    if groups is None:
        return np.zeros(n, dtype=np.int64), 1
    g = np.asarray(groups)
    check(g.shape == (n,), f"{name}: groups must have shape ({n},), got {g.shape}")
    check(bool(np.issubdtype(g.dtype, np.integer)), f"{name}: groups must be integers, got {g.dtype}")
    check(g.size == 0 or int(g.min()) >= 0, f"{name}: groups must be non-negative")
    return g.astype(np.int64), (int(g.max()) + 1 if g.size else 1)


def quantize16(x: np.ndarray, groups: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Quantize ``x (N, M)`` per column (per ``groups (N,)`` row group and column when given).

    Returns ``(codes (N, M) uint16, scale (G, M) float32, offset (G, M) float32)``, ``G = groups.max() + 1``
    (1 without groups). Groups without rows get ``scale = 0``, ``offset = 0``.
    """
    a = np.asarray(x)
    check_shape(a, "N M", name="quantize16: input")
    check(bool(np.isfinite(a).all()), "quantize16: input contains NaN or Inf")
    g, n_g = _groups(groups, a.shape[0], "quantize16")
    a = a.astype(np.float64, copy=False)
    lo = np.full((n_g, a.shape[1]), np.inf)
    hi = np.full((n_g, a.shape[1]), -np.inf)
    np.minimum.at(lo, g, a)
    np.maximum.at(hi, g, a)
    empty = ~np.isfinite(lo)
    lo[empty], hi[empty] = 0.0, 0.0
    offset = lo.astype(np.float32)
    scale = ((hi - offset.astype(np.float64)) / LEVELS).astype(np.float32)
    # float32 rounding of ``scale`` must still cover the range: bump by one ulp where it falls short
    short = offset.astype(np.float64) + scale.astype(np.float64) * LEVELS < hi
    scale[short] = np.nextafter(scale[short], np.float32(np.inf))
    s64 = scale.astype(np.float64)[g]
    safe = np.where(s64 > 0, s64, 1.0)
    q = np.rint((a - offset.astype(np.float64)[g]) / safe)
    q = np.where(s64 > 0, np.clip(q, 0, LEVELS), 0)
    return q.astype(np.uint16), scale, offset


def dequantize16(codes: np.ndarray, scale: np.ndarray, offset: np.ndarray,
                 groups: np.ndarray | None = None) -> np.ndarray:
    """Float32 ``(N, M)`` values of :func:`quantize16`'s codes: ``offset[g] + codes * scale[g]``."""
    q = np.asarray(codes)
    dims = check_shape(q, "N M", name="dequantize16: codes")
    s = np.asarray(scale, dtype=np.float64)
    o = np.asarray(offset, dtype=np.float64)
    check_shape(s, "G M", name="dequantize16: scale", dims=dims)
    check_shape(o, "G M", name="dequantize16: offset", dims=dims)
    g, n_g = _groups(groups, q.shape[0], "dequantize16")
    check(n_g <= s.shape[0], f"dequantize16: group {n_g - 1} has no scale row (G = {s.shape[0]})")
    return (o[g] + q.astype(np.float64) * s[g]).astype(np.float32)


def quantized_nbytes(n: int, m: int, n_groups: int = 1) -> int:
    """Bytes of a quantized ``(n, m)`` table: uint16 codes + float32 scale and offset per group and column."""
    return 2 * n * m + 8 * n_groups * m

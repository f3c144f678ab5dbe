"""Real SH rotation matrices of any order (Ivanic & Ruedenberg recurrence).

For a rotation ``R`` (``(3, 3)``, orthonormal, ``det = +1``) and ``g(w) = f(R^T w)`` (``f`` rotated
by ``R``), the SH coefficients satisfy ``g = D(R) @ f`` with ``D`` block diagonal, one
``(2l+1) x (2l+1)`` orthogonal block per band. In this project's basis (band 1 =
``c (y, z, x)``) band 1 is ``D^1 = P R P^T`` with ``P`` the permutation ``(x, y, z) -> (y, z, x)``;
higher bands follow from the Ivanic-Ruedenberg recurrence (J. Phys. Chem. 1996, with the 1998
erratum), band ``l`` from band ``l - 1`` and band 1.

The recurrence is tabulated once per order as a list of terms
``D^l[m, n] += coef * D^1[i, j] * D^{l-1}[a, b]`` and evaluated with gathers and one matrix product
per band, vectorised over any batch of rotations; the same code runs on numpy arrays and torch
tensors (differentiable under autograd).
"""

from __future__ import annotations

import functools
import math
from typing import TYPE_CHECKING, Any, TypeVar

import numpy as np

from prt_torch.errors import PrtError
from prt_torch.sh.basis import check_order, is_torch
from prt_torch.shapes import check_shape

if TYPE_CHECKING:
    import torch

Array = TypeVar("Array", "np.ndarray", "torch.Tensor")

_PERM = [1, 2, 0]  # SH band-1 order (y, z, x)


_Term = tuple[float, int, int, int, int]


def _scaled(terms: list[_Term], s: float) -> list[_Term]:
    return [(c * s, i, j, a, b) for c, i, j, a, b in terms]


def _p_terms(i: int, l: int, a: int, b: int) -> list[_Term]:
    """The IR function ``P(i, l, a, b)`` as terms ``(coef, i, j, a', b')`` of ``R1[i, j] * M[a', b']``.

    ``i, j`` in -1..1 and ``a', b'`` in -(l-1)..(l-1) (signed, converted to offsets by the caller).
    """
    if b == l:
        return [(1.0, i, 1, a, l - 1), (-1.0, i, -1, a, -l + 1)]
    if b == -l:
        return [(1.0, i, 1, a, -l + 1), (1.0, i, -1, a, l - 1)]
    return [(1.0, i, 0, a, b)]


@functools.cache
def _band_terms(l: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Terms of band ``l >= 2``: ``coef (T,)``, ``r1_idx (T,)`` flat into 3x3, ``prev_idx (T,)`` flat into
    ``(2l-1)^2``, ``out_idx (T,)`` flat into ``(2l+1)^2`` (sorted), ``starts ((2l+1)^2,)`` segment starts."""
    coefs: list[float] = []
    r1: list[int] = []
    prev: list[int] = []
    outs: list[int] = []
    w_prev = 2 * l - 1
    for m in range(-l, l + 1):
        for n in range(-l, l + 1):
            d = 1.0 if m == 0 else 0.0
            denom = (l + n) * (l - n) if abs(n) < l else (2 * l) * (2 * l - 1)
            u = math.sqrt((l + m) * (l - m) / denom)
            v = 0.5 * math.sqrt((1 + d) * (l + abs(m) - 1) * (l + abs(m)) / denom) * (1 - 2 * d)
            w = -0.5 * math.sqrt(max((l - abs(m) - 1) * (l - abs(m)), 0) / denom) * (1 - d)
            terms: list[_Term] = []
            if u != 0:
                terms += _scaled(_p_terms(0, l, m, n), u)
            if v != 0:
                if m == 0:
                    vt = _p_terms(1, l, 1, n) + _p_terms(-1, l, -1, n)
                elif m > 0:
                    d1 = 1.0 if m == 1 else 0.0
                    vt = _scaled(_p_terms(1, l, m - 1, n), math.sqrt(1 + d1))
                    vt += _scaled(_p_terms(-1, l, -m + 1, n), -(1 - d1))
                else:
                    d1 = 1.0 if m == -1 else 0.0
                    vt = _scaled(_p_terms(1, l, m + 1, n), 1 - d1)
                    vt += _scaled(_p_terms(-1, l, -m - 1, n), math.sqrt(1 + d1))
                terms += _scaled(vt, v)
            if w != 0:
                if m > 0:
                    wt = _p_terms(1, l, m + 1, n) + _p_terms(-1, l, -m - 1, n)
                else:
                    wt = _p_terms(1, l, m - 1, n) + _scaled(_p_terms(-1, l, -m + 1, n), -1.0)
                terms += _scaled(wt, w)
            for c, i, j, a, b in terms:
                if c == 0.0:
                    continue
                coefs.append(c)
                r1.append((i + 1) * 3 + (j + 1))
                prev.append((a + l - 1) * w_prev + (b + l - 1))
                outs.append((m + l) * (2 * l + 1) + (n + l))
    # terms are generated in output order, every output has >= 2 terms: segment sums by reduceat
    starts = np.flatnonzero(np.diff(np.asarray(outs), prepend=-1))
    assert len(starts) == (2 * l + 1) ** 2
    return (np.asarray(coefs), np.asarray(r1, dtype=np.int64), np.asarray(prev, dtype=np.int64),
            np.asarray(outs, dtype=np.int64), starts)


def _check_rotation(R: Any) -> None:
    if not (isinstance(R, np.ndarray) or is_torch(R)):
        raise PrtError(f"rotation must be a numpy array or torch tensor, got {type(R).__name__}")
    check_shape(R, "... 3 3", name="rotation")
    a = R.detach().cpu().numpy() if is_torch(R) else R
    if not np.issubdtype(a.dtype, np.floating):
        raise PrtError(f"rotation must be floating point, got {R.dtype}")
    if a.size == 0:
        return
    if not np.isfinite(a).all():
        raise PrtError("rotation contains NaN or Inf")
    tol = 1e-6 if a.dtype == np.float64 else 1e-4  # float32 frames round-trip through float64 must pass
    a = a.astype(np.float64)
    err = float(np.abs(a @ np.swapaxes(a, -1, -2) - np.eye(3)).max())
    if err > tol:
        raise PrtError(f"rotation is not orthonormal (max |R R^T - I| = {err:.3g} > {tol:g})")
    if (np.linalg.det(a) <= 0).any():
        raise PrtError("rotation has det -1 (a reflection): expected a proper rotation, det +1")


#: Rotations processed per chunk (bounds the ``(chunk, T)`` temporaries to ~100 MB at order 8).
_CHUNK = 8192


def sh_rotation_blocks(R: Array, order: int, check: bool = True) -> list[Array]:
    """Per-band blocks of :func:`sh_rotation`: ``[(..., 2l+1, 2l+1) for l < order]`` (no ``C x C`` padding).

    Same conventions, backends and validation as :func:`sh_rotation`; use this for large batches
    (e.g. one rotation per vertex) where the zero off-diagonal blocks would dominate memory.
    """
    check_order(order)
    if check:
        _check_rotation(R)
    torch_mode = is_torch(R)
    batch = tuple(R.shape[:-2])
    flat = R.reshape(-1, 3, 3)
    nb = flat.shape[0]
    if nb > _CHUNK:
        parts = [sh_rotation_blocks(flat[i : i + _CHUNK], order, check=False) for i in range(0, nb, _CHUNK)]
        if torch_mode:
            import torch

            cat = [torch.cat([p[l] for p in parts]) for l in range(order)]
        else:
            cat = [np.concatenate([p[l] for p in parts]) for l in range(order)]
        return [b.reshape(*batch, 2 * l + 1, 2 * l + 1) for l, b in enumerate(cat)]
    r1 = flat[:, _PERM, :][:, :, _PERM]  # band-1 block (B, 3, 3)
    blocks = [flat[:, :1, :1] * 0 + 1]
    if order > 1:
        blocks.append(r1)
    r1_flat = r1.reshape(nb, 9)
    prev = r1
    for l in range(2, order):
        coef, ri, pi, oi, starts = _band_terms(l)
        prev_flat = prev.reshape(nb, (2 * l - 1) ** 2)
        k = (2 * l + 1) ** 2
        if torch_mode:
            import torch

            dev = R.device
            vals = (torch.as_tensor(coef, dtype=R.dtype, device=dev) * r1_flat[:, torch.as_tensor(ri, device=dev)]
                    * prev_flat[:, torch.as_tensor(pi, device=dev)])
            cur = vals.new_zeros(nb, k).index_add(1, torch.as_tensor(oi, device=dev), vals)
        else:
            vals = coef.astype(R.dtype) * r1_flat[:, ri] * prev_flat[:, pi]
            cur = np.add.reduceat(vals, starts, axis=1)
        cur = cur.reshape(nb, 2 * l + 1, 2 * l + 1)
        blocks.append(cur)
        prev = cur
    return [b.reshape(*batch, 2 * l + 1, 2 * l + 1) for l, b in enumerate(blocks)]


def sh_rotation(R: Array, order: int, check: bool = True) -> Array:
    """Block-diagonal real SH rotation matrices ``D(R)``: coefficients of ``f(R^T w)`` are ``D @ f``.

    Args:
        R: ``(..., 3, 3)`` rotation matrices (orthonormal to 1e-6 in float64, 1e-4 in float32; det +1),
            numpy or torch, float32/float64.
        order: number of bands ``n`` (1..16); ``C = n*n``.
        check: validate ``R``.

    Returns:
        ``(..., C, C)`` in the backend, dtype and device of ``R``; orthogonal, ``D(R1 R2) = D(R1) D(R2)``.
        See :func:`sh_rotation_blocks` for the blocks alone.
    """
    blocks = sh_rotation_blocks(R, order, check=check)
    batch = tuple(R.shape[:-2])
    c = order * order
    if is_torch(R):
        out = R.new_zeros(*batch, c, c)
    else:
        out = np.zeros(batch + (c, c), dtype=R.dtype)
    for l, blk in enumerate(blocks):
        s = l * l
        out[..., s : s + 2 * l + 1, s : s + 2 * l + 1] = blk
    return out

"""numpy twin of :func:`prt_torch.models.local.local_offsets` for the player (numpy only, vertex-last).

onnxruntime's Gather of ``V x S`` neighbour coordinates costs ~1.5 ms per coordinate at 7.7k vertices and 24
samples (any axis, measured); here the whole input costs ~0.8 ms (numpy ``take`` of contiguous coordinate rows,
then 9 multiply-adds). So the player computes
the local model's input here and runs only the network (:class:`prt_torch.models.local.LocalHead`) in onnxruntime,
as it does with the dihedral angles (:mod:`prt_torch.deform.dihedral_soa`).
"""

from __future__ import annotations

import numpy as np

from prt_torch.errors import PrtError, check


class LocalOffsetsSoA:
    """``positions (B, 3, V)``, ``frames (B, 9, V)`` (entry ``3 k + c`` = ``F[k, c]``, rows t, b, n) ->
    ``(B, 3 S, V)`` float32: row ``k S + s`` is frame row ``k`` dotted with neighbour ``s``'s offset (the
    component-major order of :func:`prt_torch.models.local.local_offsets`)."""

    def __init__(self, neighbours: np.ndarray) -> None:
        nb = np.asarray(neighbours)
        check(nb.ndim == 2 and nb.size > 0, f"neighbours must be a non-empty (V, S) array, got {nb.shape}")
        check(np.issubdtype(nb.dtype, np.integer) and nb.min() >= 0 and nb.max() < nb.shape[0],
              f"neighbour indices must be integers in 0..{nb.shape[0] - 1}")
        self.n_vertices, self.n_samples = int(nb.shape[0]), int(nb.shape[1])
        self._idx = np.ascontiguousarray(nb.T, dtype=np.intp).ravel()  # (S * V,) sample-major

    def __call__(self, positions_soa: np.ndarray, frames_soa: np.ndarray) -> np.ndarray:
        p = np.ascontiguousarray(positions_soa, dtype=np.float32)
        f = np.ascontiguousarray(frames_soa, dtype=np.float32)
        v, s = self.n_vertices, self.n_samples
        if p.ndim != 3 or p.shape[1:] != (3, v) or f.shape != (p.shape[0], 9, v):
            raise PrtError(f"local offsets need positions (B, 3, {v}) and frames (B, 9, {v}), got {p.shape} and "
                           f"{f.shape}")
        b = p.shape[0]
        out = np.empty((b, 3, s, v), np.float32)
        for i in range(b):
            d = np.take(p[i], self._idx, axis=1).reshape(3, s, v)
            d -= p[i][:, None, :]
            fi = f[i]
            for k in range(3):
                o = out[i, k]
                np.multiply(d[0], fi[3 * k], out=o)
                o += d[1] * fi[3 * k + 1]
                o += d[2] * fi[3 * k + 2]
        return out.reshape(b, 3 * s, v)


def offsets_inputs(positions: np.ndarray, frames: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``positions (F, V, 3)``, ``frames (F, V, 3, 3)`` -> the player's vertex-last ``(F, 3, V)``, ``(F, 9, V)``."""
    p = np.ascontiguousarray(np.asarray(positions, np.float32).transpose(0, 2, 1))
    f = np.asarray(frames, np.float32)
    return p, np.ascontiguousarray(f.reshape(f.shape[0], f.shape[1], 9).transpose(0, 2, 1))

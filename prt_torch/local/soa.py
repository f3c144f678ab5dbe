"""Run-time twin of :func:`prt_torch.local.models.local_offsets` for the player (numba, or numpy; vertex-last).

onnxruntime's Gather of ``V x S`` neighbour coordinates costs ~1.5 ms per coordinate at 7.7k vertices and 24
samples (any axis, measured), and the same rule in numpy (``take`` of the coordinate rows, then 9 multiply-adds
over ``(S, V)`` temporaries) ~2.5 ms at the cape's 11.2k vertices and 40 samples. One compiled pass (numba:
gather, subtract and rotate per sample, no temporaries, GIL released) does it in about half the time (``prt bench
play`` measures both: ``local_offsets`` and ``local_offsets_numpy``). So the player computes the local model's
input here and runs only the network (:class:`prt_torch.local.models.LocalHead`) in onnxruntime, as it does with
the dihedral angles (:mod:`prt_torch.deform.dihedral_soa`).
"""

from __future__ import annotations

import numba
import numpy as np

from prt_torch.errors import check
from prt_torch.shapes import check_shape


@numba.njit(cache=True, nogil=True, fastmath={"contract"})
def _offsets_kernel(p: np.ndarray, f: np.ndarray, idx: np.ndarray, out: np.ndarray) -> None:  # pragma: no cover
    """``p (3, V)``, ``f (9, V)`` float32, ``idx (S, V)`` int32 -> ``out (3 S, V)``: row ``k S + s`` is frame row
    ``k`` dotted with ``p[:, idx[s]] - p`` (compiled; the loop over vertices is the vectorised inner loop)."""
    n_s, n_v = idx.shape
    for s in range(n_s):
        for v in range(n_v):
            n = idx[s, v]
            d0 = p[0, n] - p[0, v]
            d1 = p[1, n] - p[1, v]
            d2 = p[2, n] - p[2, v]
            out[s, v] = f[0, v] * d0 + f[1, v] * d1 + f[2, v] * d2
            out[n_s + s, v] = f[3, v] * d0 + f[4, v] * d1 + f[5, v] * d2
            out[2 * n_s + s, v] = f[6, v] * d0 + f[7, v] * d1 + f[8, v] * d2


class LocalOffsetsSoA:
    """``positions (B, 3, V)``, ``frames (B, 9, V)`` (entry ``3 k + c`` = ``F[k, c]``, rows t, b, n) ->
    ``(B, 3 S, V)`` float32: row ``k S + s`` is frame row ``k`` dotted with neighbour ``s``'s offset (the
    component-major order of :func:`prt_torch.local.models.local_offsets`).

    ``engine``: ``"numba"`` (default: one compiled pass) or ``"numpy"`` (``take`` + multiply-adds; the same values
    to float rounding, kept for the benchmark's side-by-side)."""

    ENGINES = ("numba", "numpy")

    def __init__(self, neighbours: np.ndarray, engine: str = "numba") -> None:
        nb = np.asarray(neighbours)
        check(nb.ndim == 2 and nb.size > 0, f"neighbours must be a non-empty (V, S) array, got {nb.shape}")
        check(np.issubdtype(nb.dtype, np.integer) and nb.min() >= 0 and nb.max() < nb.shape[0],
              f"neighbour indices must be integers in 0..{nb.shape[0] - 1}")
        check(engine in self.ENGINES, f"unknown local offsets engine {engine!r}: expected one of {list(self.ENGINES)}")
        self.engine = engine
        self.n_vertices, self.n_samples = int(nb.shape[0]), int(nb.shape[1])
        self._idx2 = np.ascontiguousarray(nb.T, dtype=np.int32)  # (S, V) sample-major
        # (S * V,) for numpy's take; the compiled pass reads _idx2
        self._idx: np.ndarray | None = self._idx2.ravel().astype(np.intp) if engine == "numpy" else None

    @property
    def neighbours(self) -> np.ndarray:
        """``(V, S)`` int32 neighbour indices (a view)."""
        return self._idx2.T

    def __call__(self, positions_soa: np.ndarray, frames_soa: np.ndarray) -> np.ndarray:
        p = np.ascontiguousarray(positions_soa, dtype=np.float32)
        f = np.ascontiguousarray(frames_soa, dtype=np.float32)
        v, s = self.n_vertices, self.n_samples
        dims = check_shape(p, ("B", 3, v), name="local offsets: positions")
        check_shape(f, ("B", 9, v), name="local offsets: frames", dims=dims)
        b = p.shape[0]
        out = np.empty((b, 3 * s, v), np.float32)
        for i in range(b):
            if self.engine == "numba":
                _offsets_kernel(p[i], f[i], self._idx2, out[i])
            else:
                self._numpy(p[i], f[i], out[i].reshape(3, s, v))
        return out

    def _numpy(self, p: np.ndarray, f: np.ndarray, out: np.ndarray) -> None:
        v, s = self.n_vertices, self.n_samples
        d = np.take(p, self._idx, axis=1).reshape(3, s, v)
        d -= p[:, None, :]
        for k in range(3):
            o = out[k]
            np.multiply(d[0], f[3 * k], out=o)
            o += d[1] * f[3 * k + 1]
            o += d[2] * f[3 * k + 2]


def offsets_inputs(positions: np.ndarray, frames: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``positions (F, V, 3)``, ``frames (F, V, 3, 3)`` -> the player's vertex-last ``(F, 3, V)``, ``(F, 9, V)``."""
    p = np.ascontiguousarray(np.asarray(positions, np.float32).transpose(0, 2, 1))
    f = np.asarray(frames, np.float32)
    return p, np.ascontiguousarray(f.reshape(f.shape[0], f.shape[1], 9).transpose(0, 2, 1))

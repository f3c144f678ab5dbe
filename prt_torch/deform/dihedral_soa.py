"""Signed dihedral angles, numpy only: THE numpy rule (:func:`prt_torch.deform.dihedral.dihedral_angles` is this on
``(..., V, 3)`` positions; see its docstring for the sign convention), in the form of the exported graph's
:class:`prt_torch.deform.dihedral_torch.DihedralAngles` (tested against both): for an edge
row ``(i, j, k, l)`` with ``e = x_j - x_i``, ``a = x_k - x_i``, ``b = x_l - x_j`` and ``n1 = e x a``::

    theta = atan2(|e| (b . n1), (e . b)(a . e) - (e . e)(a . b))

(``n2 x n1 = e (b . n1)`` and Binet-Cauchy for ``n1 . n2``; the numpy rule with the positive factor ``|e|`` removed).

Why a second layout: the four corners of every edge are a gather of ``4E`` vertices. onnxruntime's ``Gather`` of
12-byte rows takes ~0.7 ms for the 7.7k flag's 22k edges (half the positions graph), numpy's fancy indexing of
``(V, 3)`` rows ~0.85 ms, but ``ndarray.take`` of a contiguous ``(V,)`` coordinate row ~0.05 ms: so the positions
come vertex-last ``(B, 3, V)`` (the frames' layout, :meth:`prt_torch.deform.frames.FrameOperator.frames_soa`), each
coordinate row is gathered once with the precomputed corner indices, and every product below is an elementwise
operation on contiguous ``(E,)`` rows (about 6x faster than the graph's features on one core, measured on the
7.7k flag; ``prt bench play``).
"""

from __future__ import annotations

import numpy as np

from prt_torch.errors import check
from prt_torch.shapes import check_shape


def check_edges(edges: np.ndarray, n_vertices: int) -> np.ndarray:
    """Validate ``(E, 4)`` integer edge rows indexing ``n_vertices`` vertices; returns them as intp."""
    e = np.asarray(edges)
    check_shape(e, "E 4", name="dihedral edges")
    check(np.issubdtype(e.dtype, np.integer), f"dihedral edges must be integers, got {e.dtype}")
    if e.size:
        check(int(e.min()) >= 0 and int(e.max()) < n_vertices,
              f"dihedral edge index out of range [0, {n_vertices}): min {int(e.min())}, max {int(e.max())}")
    return e.astype(np.intp)


class DihedralSoA:
    """``positions (B, 3, V)`` float32 (float64 stays float64) -> ``(B, E)`` signed dihedral angles in
    ``(-pi, pi]`` of the edge rows ``edges (E, 4)`` (module docstring). Fixed data: the corner indices, gathered
    in one ``take`` per coordinate row."""

    def __init__(self, edges: np.ndarray, n_vertices: int) -> None:
        e = check_edges(np.asarray(edges), int(n_vertices))
        check(e.shape[0] > 0, "DihedralSoA: no edges")
        self.n_edges = int(e.shape[0])
        self.n_vertices = int(n_vertices)
        self.corners = np.ascontiguousarray(e.astype(np.intp).T.reshape(-1))  # (4E,): the i's, j's, k's, l's

    def __call__(self, positions_soa: np.ndarray) -> np.ndarray:
        p = np.asarray(positions_soa)
        p = np.ascontiguousarray(p, dtype=np.float64 if p.dtype == np.float64 else np.float32)  # float64 stays
        v, n = self.n_vertices, self.n_edges
        check_shape(p, ("B", 3, v), name="positions")
        out = np.empty((p.shape[0], n), p.dtype)
        for bi in range(p.shape[0]):
            g = [p[bi, c].take(self.corners).reshape(4, n) for c in range(3)]  # x, y, z of the 4 corners
            e = [gc[1] - gc[0] for gc in g]
            a = [gc[2] - gc[0] for gc in g]
            b = [gc[3] - gc[1] for gc in g]
            del g
            ee, eb, ae, ab = _dot3(e, e), _dot3(e, b), _dot3(a, e), _dot3(a, b)
            c = eb * ae
            ab *= ee
            c -= ab
            # y = |e| (b . (e x a))
            y = e[1] * a[2]
            y -= e[2] * a[1]
            y *= b[0]
            t = e[2] * a[0]
            t -= e[0] * a[2]
            t *= b[1]
            y += t
            np.multiply(e[0], a[1], out=t)
            t -= e[1] * a[0]
            t *= b[2]
            y += t
            np.sqrt(ee, out=ee)
            y *= ee
            r = np.arctan2(y, c, out=out[bi])
            r[r <= -np.pi] = p.dtype.type(np.pi)  # (-pi, pi]: -pi (rounded) -> +pi
        return out


def _dot3(u: list[np.ndarray], w: list[np.ndarray]) -> np.ndarray:
    """``u . w`` of two coordinate triples of ``(E,)`` rows: one new row, the other two products added in place."""
    d = u[0] * w[0]
    d += u[1] * w[1]
    d += u[2] * w[2]
    return d

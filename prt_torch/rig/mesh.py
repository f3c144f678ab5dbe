"""Mesh helpers for skinned characters: welding duplicate vertices and smooth normals (numpy)."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from prt_torch.shapes import check_shape

if TYPE_CHECKING:
    import scipy.sparse


def weld(positions: np.ndarray, faces: np.ndarray, *keys: np.ndarray, decimals: int = 6
         ) -> tuple[np.ndarray, np.ndarray, list[np.ndarray], np.ndarray]:
    """Merge vertices whose position (rounded to ``decimals``) AND every per-vertex array in ``keys`` are equal.

    ``positions (V, 3)``, ``faces (T, 3)``, ``keys``: arrays ``(V, ...)`` (e.g. skin joints and weights).
    Returns ``(positions (V', 3), faces (T', 3), [key (V', ...)], index (V,))`` with ``index`` mapping
    each input vertex to its welded vertex; the first occurrence of each vertex is kept (order
    preserved) and faces that become degenerate are dropped.
    """
    positions = np.asarray(positions)
    v = positions.shape[0]
    cols = [np.round(positions.astype(np.float64), decimals).reshape(v, -1)]
    cols += [np.round(np.asarray(k, dtype=np.float64).reshape(v, -1), decimals) for k in keys]
    table = np.ascontiguousarray(np.concatenate(cols, axis=1))
    _, first, inverse = np.unique(table, axis=0, return_index=True, return_inverse=True)
    inverse = inverse.reshape(-1)
    order = np.argsort(first)  # keep first-occurrence order
    remap = np.empty_like(order)
    remap[order] = np.arange(order.size)
    keep = first[order]
    new_faces = remap[inverse[np.asarray(faces)]]
    ok = ((new_faces[:, 0] != new_faces[:, 1]) & (new_faces[:, 1] != new_faces[:, 2])
          & (new_faces[:, 0] != new_faces[:, 2]))
    return positions[keep], new_faces[ok].astype(np.int64), [np.asarray(k)[keep] for k in keys], remap[inverse]


def vertex_normals(positions: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Smooth area-weighted vertex normals ``(V, 3)`` float32 (sum of unnormalised face normals, normalised).

    Faces are counter-clockwise seen from outside. Isolated vertices get ``(0, 0, 1)``.
    """
    p = np.asarray(positions, dtype=np.float64)
    faces = np.asarray(faces, dtype=np.int64)
    check_shape(faces, "T 3", name="faces")
    fn = np.cross(p[faces[:, 1]] - p[faces[:, 0]], p[faces[:, 2]] - p[faces[:, 0]])  # 2 * area * normal
    n = np.zeros_like(p)
    for c in range(3):
        np.add.at(n, faces[:, c], fn)
    length = np.linalg.norm(n, axis=1, keepdims=True)
    n = np.where(length > 1e-20, n / np.maximum(length, 1e-30), np.array([0.0, 0.0, 1.0]))
    return n.astype(np.float32)


def normal_scatter(faces: np.ndarray, n_vertices: int) -> scipy.sparse.csr_matrix:
    """``(V, T)`` float32 CSR incidence matrix (1 where vertex ``v`` is a corner of face ``t``) for
    :func:`vertex_normals_soa`: summing face normals onto their corners as one sparse product."""
    import scipy.sparse as sp

    faces = np.asarray(faces, dtype=np.int64)
    check_shape(faces, "T 3", name="faces")
    t = np.repeat(np.arange(faces.shape[0]), 3)
    return sp.csr_matrix((np.ones(t.size, np.float32), (faces.reshape(-1), t)), shape=(n_vertices, faces.shape[0]))


def vertex_normals_soa(positions: np.ndarray, faces: np.ndarray, scatter: scipy.sparse.csr_matrix | None = None
                       ) -> np.ndarray:
    """The rule of :func:`vertex_normals` in float32, vertex-last (the player's fast path; tested against it).

    Args:
        positions: ``(B, 3, V)`` float32 positions.
        faces: ``(T, 3)`` counter-clockwise triangles.
        scatter: :func:`normal_scatter` ``(faces, V)`` (built here when ``None``; pass it for speed).

    Returns:
        ``(B, 3, V)`` float32 unit normals; isolated vertices get ``(0, 0, 1)``.
    """
    p = np.asarray(positions, dtype=np.float32)
    check_shape(p, "B 3 V", name="positions")
    b, _, v = p.shape
    faces = np.asarray(faces)
    if scatter is None:
        scatter = normal_scatter(faces, v)
    g = np.take(p, faces.T.reshape(-1), axis=2).reshape(b, 3, 3, -1)  # (B, xyz, corner, T)
    e1 = g[:, :, 1] - g[:, :, 0]
    e2 = g[:, :, 2] - g[:, :, 0]
    fn = np.empty_like(e1)  # (B, 3, T): e1 x e2 = 2 * area * normal
    np.multiply(e1[:, 1], e2[:, 2], out=fn[:, 0])
    fn[:, 0] -= e1[:, 2] * e2[:, 1]
    np.multiply(e1[:, 2], e2[:, 0], out=fn[:, 1])
    fn[:, 1] -= e1[:, 0] * e2[:, 2]
    np.multiply(e1[:, 0], e2[:, 1], out=fn[:, 2])
    fn[:, 2] -= e1[:, 1] * e2[:, 0]
    n = np.empty((b, 3, v), np.float32)
    for i in range(b):  # one sparse mat-vec per row: much faster than one sparse mat-multivector product
        for c in range(3):
            n[i, c] = scatter @ fn[i, c]
    length = np.sqrt(np.einsum("bcv,bcv->bv", n, n))
    iso = length <= 1e-20
    n /= np.where(iso, np.float32(1), length)[:, None]
    if iso.any():
        n[:, 2][iso] = 1.0
    return n

"""Mesh helpers for skinned characters: welding duplicate vertices and smooth normals (numpy)."""

from __future__ import annotations

import numpy as np

from prt_torch.errors import check


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
    check(faces.ndim == 2 and faces.shape[1] == 3, f"faces must be (T, 3), got {faces.shape}")
    fn = np.cross(p[faces[:, 1]] - p[faces[:, 0]], p[faces[:, 2]] - p[faces[:, 0]])  # 2 * area * normal
    n = np.zeros_like(p)
    for c in range(3):
        np.add.at(n, faces[:, c], fn)
    length = np.linalg.norm(n, axis=1, keepdims=True)
    n = np.where(length > 1e-20, n / np.maximum(length, 1e-30), np.array([0.0, 0.0, 1.0]))
    return n.astype(np.float32)

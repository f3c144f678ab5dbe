"""Checks and edge tables of deformable triangle meshes (cloth). numpy only.

Orientation convention: faces are counter-clockwise seen from the side their normals point to (as
:func:`prt_torch.rig.mesh.vertex_normals`). A mesh is *consistently oriented* when every edge shared by two
faces is traversed in opposite directions by them: face ``(i, j, k)`` contains the directed edge ``i -> j``
and its neighbour ``(j, i, l)`` contains ``j -> i``.
"""

from __future__ import annotations

import numpy as np

from prt_torch.errors import PrtError, check
from prt_torch.shapes import check_shape

#: a face whose area is below this fraction of the squared bounding-box diagonal is degenerate
DEGENERATE_AREA = 1e-14


def _faces(faces: np.ndarray, what: str) -> np.ndarray:
    f = np.asarray(faces)
    check_shape(f, "T 3", name=f"{what}: faces")
    check(f.shape[0] > 0, f"{what}: faces must have shape (T, 3) with T > 0, got {f.shape}")
    check(np.issubdtype(f.dtype, np.integer), f"{what}: faces must be integers, got {f.dtype}")
    return f.astype(np.int64)


def _half_edges(faces: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Directed half-edges of every face: ``(src, dst, opposite)`` each ``(3T,)``, face-major order."""
    src = faces.reshape(-1)
    dst = faces[:, [1, 2, 0]].reshape(-1)
    opp = faces[:, [2, 0, 1]].reshape(-1)
    return src, dst, opp


def _edge_groups(faces: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Half-edges sorted by their undirected key ``(min, max)``.

    Returns ``(src, dst, opp, start, count)``: the sorted half-edges and, per distinct undirected edge, the start
    index of its group in the sorted order and the number of half-edges (faces) sharing it.
    """
    src, dst, opp = _half_edges(faces)
    lo, hi = np.minimum(src, dst), np.maximum(src, dst)
    order = np.lexsort((dst, src, hi, lo))  # primary lo, then hi; ties broken deterministically
    src, dst, opp, lo, hi = src[order], dst[order], opp[order], lo[order], hi[order]
    new = np.ones(lo.size, dtype=bool)
    new[1:] = (lo[1:] != lo[:-1]) | (hi[1:] != hi[:-1])
    start = np.flatnonzero(new)
    count = np.diff(np.append(start, lo.size))
    return src, dst, opp, start, count


def check_deformable_mesh(vertices: np.ndarray, faces: np.ndarray, what: str) -> None:
    """Raise a one-line :class:`PrtError` (prefixed by ``what``) unless the mesh is a valid deformable surface.

    Checked: ``vertices (V, 3)`` finite (no NaN/inf), ``faces (T, 3)`` integers in ``[0, V)``, no degenerate face
    (a repeated index, or area below :data:`DEGENERATE_AREA` times the squared bounding-box diagonal), no
    non-manifold edge (shared by more than two faces), consistent orientation (an edge shared by two faces is
    traversed in opposite directions). Boundaries and several components are allowed.
    """
    v = np.asarray(vertices)
    check_shape(v, "V 3", name=f"{what}: vertices")
    check(np.issubdtype(v.dtype, np.number), f"{what}: vertices must be numbers, got {v.dtype}")
    bad = ~np.isfinite(v).all(axis=1)
    check(not bad.any(), f"{what}: {int(bad.sum())} vertex positions are NaN or inf (first: vertex "
          f"{int(np.argmax(bad)) if bad.any() else -1})")
    f = _faces(faces, what)
    lo, hi = int(f.min()), int(f.max())
    check(lo >= 0 and hi < v.shape[0], f"{what}: face index out of range [0, {v.shape[0]}): min {lo}, max {hi}")
    rep = (f[:, 0] == f[:, 1]) | (f[:, 1] == f[:, 2]) | (f[:, 0] == f[:, 2])
    check(not rep.any(), f"{what}: degenerate face {int(np.argmax(rep)) if rep.any() else -1} repeats a vertex")
    p = v.astype(np.float64)
    area2 = np.linalg.norm(np.cross(p[f[:, 1]] - p[f[:, 0]], p[f[:, 2]] - p[f[:, 0]]), axis=1)
    diag2 = float(np.sum((p.max(axis=0) - p.min(axis=0)) ** 2))
    tiny = area2 <= 2.0 * DEGENERATE_AREA * diag2
    check(not tiny.any(), f"{what}: {int(tiny.sum())} degenerate (zero-area) faces (first: face "
          f"{int(np.argmax(tiny)) if tiny.any() else -1})")
    src, dst, _, start, count = _edge_groups(f)
    many = count > 2
    if many.any():
        s = start[np.argmax(many)]
        raise PrtError(f"{what}: {int(many.sum())} non-manifold edges shared by more than two faces (first: edge "
                       f"({int(min(src[s], dst[s]))}, {int(max(src[s], dst[s]))}) in {int(count[many][0])} faces)")
    pair = start[count == 2]
    same = src[pair] == src[pair + 1]  # both faces traverse the edge in the same direction
    if same.any():
        s = pair[np.argmax(same)]
        raise PrtError(f"{what}: inconsistent face orientation at {int(same.sum())} edges (first: edge "
                       f"({int(src[s])}, {int(dst[s])}) traversed the same way by two faces)")


def interior_edges(faces: np.ndarray) -> np.ndarray:
    """Interior edges and their two opposite vertices.

    Args:
        faces: ``(T, 3)`` consistently oriented triangles (see module docstring).

    Returns:
        ``(E, 4)`` int64 rows ``(i, j, k, l)`` with ``i < j``: the edge ``(i, j)`` is shared by the faces
        ``(i, j, k)`` and ``(j, i, l)`` (each up to a cyclic rotation). Rows are sorted by ``(i, j)``
        (deterministic). Boundary edges (one face) are left out.

    Raises:
        PrtError: an edge shared by more than two faces, or by two faces with the same direction.
    """
    f = _faces(faces, "interior_edges")
    check(f.min() >= 0, "interior_edges: negative face index")
    src, dst, opp, start, count = _edge_groups(f)
    check(not (count > 2).any(), f"interior_edges: {int((count > 2).sum())} non-manifold edges shared by more than "
          "two faces")
    pair = start[count == 2]
    check(not (src[pair] == src[pair + 1]).any(), "interior_edges: inconsistent face orientation (an edge is "
          "traversed the same way by two faces)")
    # within a group, half-edges are sorted by src: the first one goes lo -> hi, i.e. i -> j
    return np.stack([src[pair], dst[pair], opp[pair], opp[pair + 1]], axis=1).astype(np.int64)


def edge_pairs(faces: np.ndarray, n_vertices: int) -> np.ndarray:
    """``(M, 2)`` int64 unique undirected edges ``(i, j)``, ``i < j``, sorted: the mesh's one-ring adjacency."""
    f = _faces(faces, "edge_pairs")
    src, dst, _ = _half_edges(f)
    key = np.minimum(src, dst) * np.int64(n_vertices) + np.maximum(src, dst)
    key = np.unique(key)
    return np.stack([key // n_vertices, key % n_vertices], axis=1)

"""Closed isosurfaces of a sampled implicit function by naive surface nets (numpy, vectorised).

One vertex per grid cell whose corners change sign (the mean of the edge crossings), one quad per
sign-changing grid edge joining the four cells around it, split into two triangles along the
shorter diagonal. Faces are oriented counter-clockwise seen from the positive (outside) side.
The result is closed when the function is positive on the grid boundary.

Manifoldness: a cell whose inside corners (or outside corners) are not connected through cube
edges (a checkerboard face or an interior ambiguity) would give a non-manifold edge or vertex.
Before extraction such cells are made simple by moving their outside corner with the smallest value
just inside (repeated until none is left; monotone, so it terminates). Vertices are placed from the
edge crossings, so this only changes the surface at sub-cell scale. With every cell simple each
cell's patch is a disk and the surface is a closed 2-manifold.
"""

from __future__ import annotations

import numpy as np

from prt_torch.errors import check

_CORNERS = [(a, b, c) for a in (0, 1) for b in (0, 1) for c in (0, 1)]  # corner k = 4a + 2b + c


def _simple_table() -> np.ndarray:
    """``(256,)`` bool: for each corner-sign pattern, are the inside and the outside corners each connected?"""
    edges = [(i, j) for i in range(8) for j in range(i + 1, 8) if bin(i ^ j).count("1") == 1]

    def connected(members: list[int]) -> bool:
        if len(members) <= 1:
            return True
        seen, todo = {members[0]}, [members[0]]
        while todo:
            k = todo.pop()
            for i, j in edges:
                for a, b in ((i, j), (j, i)):
                    if a == k and b in members and b not in seen:
                        seen.add(b)
                        todo.append(b)
        return len(seen) == len(members)

    return np.array([connected([k for k in range(8) if m >> k & 1]) and connected([k for k in range(8)
                                                                                   if not m >> k & 1])
                     for m in range(256)])


_SIMPLE = _simple_table()


def make_cells_simple(values: np.ndarray) -> np.ndarray:
    """Copy of ``values (nx, ny, nz)`` where every cell's inside and outside corners are connected (see above).

    Monotone: each round moves, in every non-simple cell, its outside corner with the smallest value
    just inside. Corners only ever move inside and a cell with all corners inside is simple, so the
    loop terminates; the surface grows by less than a cell where it was ambiguous.
    """
    f = np.array(values, dtype=np.float64)
    n = np.array(f.shape) - 1
    offsets = np.array(_CORNERS)
    while True:
        inside = f < 0
        code = np.zeros(tuple(n), dtype=np.int64)
        for k, (a, b, c) in enumerate(_CORNERS):
            code |= inside[a:a + n[0], b:b + n[1], c:c + n[2]].astype(np.int64) << k
        bad = np.argwhere(~_SIMPLE[code])
        if bad.size == 0:
            return f
        idx = bad[:, None, :] + offsets[None]  # (B, 8, 3)
        val = f[idx[..., 0], idx[..., 1], idx[..., 2]]
        val[val < 0] = np.inf
        i, j, k = np.unique(idx[np.arange(len(bad)), np.argmin(val, axis=1)], axis=0).T
        f[i, j, k] = -1e-9 * np.maximum(1.0, np.abs(f[i, j, k]))


def surface_nets(values: np.ndarray, origin: np.ndarray, spacing: float) -> tuple[np.ndarray, np.ndarray]:
    """Zero isosurface of ``values (nx, ny, nz)`` (negative inside) sampled at ``origin + spacing * (i, j, k)``.

    Returns ``vertices (V, 3)`` float64 and ``faces (T, 3)`` int64.
    """
    f = np.asarray(values, dtype=np.float64)
    check(f.ndim == 3 and min(f.shape) >= 3, f"grid values must be (nx, ny, nz) with every n >= 3, got {f.shape}")
    check(bool(np.all(np.isfinite(f))), "implicit function values contain NaN or inf")
    check(bool(np.all(f[[0, -1]] > 0) and np.all(f[:, [0, -1]] > 0) and np.all(f[:, :, [0, -1]] > 0)),
          "implicit function must be positive on the grid boundary")
    f = make_cells_simple(f)
    inside = f < 0
    cell_shape = tuple(n - 1 for n in f.shape)
    acc = np.zeros((*cell_shape, 3))
    cnt = np.zeros(cell_shape)
    edge_sign = []
    for axis in range(3):
        sl0 = [slice(None)] * 3
        sl1 = [slice(None)] * 3
        sl0[axis] = slice(0, -1)
        sl1[axis] = slice(1, None)
        f0, f1 = f[tuple(sl0)], f[tuple(sl1)]
        cross = inside[tuple(sl0)] != inside[tuple(sl1)]
        edge_sign.append(np.where(cross, np.where(inside[tuple(sl0)], 1, -1), 0).astype(np.int8))
        t = np.where(cross, f0 / np.where(cross, f0 - f1, 1.0), 0.0)
        idx = np.indices(f0.shape, dtype=np.float64)
        pts = np.stack([idx[0], idx[1], idx[2]], axis=-1)
        pts[..., axis] += t
        pts *= cross[..., None]
        # each edge touches the 4 cells that share it (offsets 0/1 along the two other axes)
        others = [a for a in range(3) if a != axis]
        for d0 in (0, 1):
            for d1 in (0, 1):
                src = [slice(None)] * 3
                src[others[0]] = slice(d0, d0 + cell_shape[others[0]])
                src[others[1]] = slice(d1, d1 + cell_shape[others[1]])
                acc += pts[tuple(src)]
                cnt += cross[tuple(src)]
    active = cnt > 0
    cell_id = -np.ones(cell_shape, dtype=np.int64)
    cell_id[active] = np.arange(int(active.sum()))
    verts = acc[active] / cnt[active][:, None]
    quads = []
    for axis in range(3):
        s = edge_sign[axis]
        a1, a2 = [(1, 2), (2, 0), (0, 1)][axis]  # (a1, a2, axis) right-handed
        # interior edges only: the neighbour cells at -1 along a1 and a2 must exist
        sel = [slice(None)] * 3
        sel[a1] = slice(1, s.shape[a1] - 1)
        sel[a2] = slice(1, s.shape[a2] - 1)
        sub = s[tuple(sel)]
        ii = np.nonzero(sub)
        e = [ii[0].copy(), ii[1].copy(), ii[2].copy()]
        e[a1] += 1
        e[a2] += 1
        sign = sub[ii]

        def cell(da: int, db: int, e: list[np.ndarray] = e, a1: int = a1, a2: int = a2) -> np.ndarray:
            c = [e[0].copy(), e[1].copy(), e[2].copy()]
            c[a1] -= da
            c[a2] -= db
            return cell_id[c[0], c[1], c[2]]

        q = np.stack([cell(1, 1), cell(0, 1), cell(0, 0), cell(1, 0)], axis=1)  # CCW about +axis
        q[sign < 0] = q[sign < 0][:, ::-1]
        quads.append(q)
    q = np.concatenate(quads)
    check(bool(np.all(q >= 0)), "surface nets: a quad refers to an inactive cell (function not continuous?)")
    vw = origin + spacing * verts
    d02 = np.linalg.norm(vw[q[:, 0]] - vw[q[:, 2]], axis=1)
    d13 = np.linalg.norm(vw[q[:, 1]] - vw[q[:, 3]], axis=1)
    use02 = d02 <= d13
    t1 = np.where(use02[:, None], q[:, [0, 1, 2]], q[:, [0, 1, 3]])
    t2 = np.where(use02[:, None], q[:, [0, 2, 3]], q[:, [1, 2, 3]])
    return vw, np.concatenate([t1, t2]).astype(np.int64)

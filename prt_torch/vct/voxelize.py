"""Voxelisation of a posed triangle mesh into a dense ``(R, R, R)`` opacity grid (torch, vectorised).

* **Surface** (conservative): every triangle is sampled on a barycentric lattice with ``s`` subdivisions, ``s``
  chosen so the lattice spacing along the longest edge is at most half a voxel; every point of the triangle lies
  within 0.29 voxel of a sample, so each sample marks the voxels of the 8 corners of a cube of half-size 0.3
  voxel about it (every voxel the triangle touches is marked; the shell thickens by at most ~half a voxel).
  Triangles are grouped into a few buckets of equal ``s`` (a loop over <= ~12 buckets, never over triangles).
* **Solid** (closed meshes, by ray parity): one ray per voxel column along +z, through the column centre
  (jittered by ~1e-3 voxel so no ray meets a mesh edge exactly); each triangle is tested against the columns
  of its xy bounding box (bucketed by box size), its crossings are histogrammed per column and a voxel is
  inside when an odd number of crossings lies below its centre (a cumulative sum along z).

The opacity is 1 in occupied voxels and 0 elsewhere; index order ``[i, j, k] = [x, y, z]``.
"""

from __future__ import annotations

import math

import numpy as np
import torch

from prt_torch.errors import check
from prt_torch.shapes import check_shape
from prt_torch.vct.grid import VoxelGrid, check_positions

#: lattice subdivisions available to the surface sampler (buckets)
_SUBDIVISIONS = (1, 2, 3, 4, 6, 8, 12, 16, 24, 32, 48, 64, 96, 128, 192, 256, 384, 512, 768, 1024)
#: corners of the cube (half-size 0.3 voxel) each lattice sample marks
_CORNERS = 0.3 * torch.tensor([[x, y, z] for x in (-1.0, 1.0) for y in (-1.0, 1.0) for z in (-1.0, 1.0)])
#: column-window sizes available to the parity fill (buckets)
_WINDOWS = (1, 2, 3, 4, 6, 8, 12, 16, 24, 32, 48, 64, 96, 128, 192, 256, 384, 512)
#: the parity rays' offset from the column centres, in voxels (irrational, so no ray hits an edge exactly)
_JITTER = (1e-3 * math.sqrt(2.0), 1e-3 * math.sqrt(3.0))


def is_closed_mesh(faces: np.ndarray | torch.Tensor) -> bool:
    """Whether every undirected edge of ``faces (T, 3)`` is shared by exactly two triangles (solid fill is
    meaningful only then)."""
    f = np.asarray(faces.cpu() if isinstance(faces, torch.Tensor) else faces, dtype=np.int64)
    if f.ndim != 2 or f.shape[1] != 3 or len(f) == 0:
        return False
    e = np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1)
    _, counts = np.unique(e, axis=0, return_counts=True)
    return bool((counts == 2).all())


def _bucket(values: torch.Tensor, table: tuple[int, ...]) -> torch.Tensor:
    """Index into ``table`` of the smallest entry >= each value (the last entry caps)."""
    t = torch.as_tensor(table, dtype=values.dtype, device=values.device)
    return torch.searchsorted(t, values.contiguous()).clamp_(max=len(table) - 1)


def _lattice(s: int, device: torch.device, dtype: torch.dtype) -> torch.Tensor:
    """``(M, 3)`` barycentric weights of the lattice ``(i/s, j/s, 1 - i/s - j/s)``, ``i + j <= s``."""
    i, j = torch.meshgrid(torch.arange(s + 1, device=device), torch.arange(s + 1, device=device), indexing="ij")
    keep = (i + j) <= s
    a = i[keep].to(dtype) / s
    b = j[keep].to(dtype) / s
    return torch.stack([a, b, 1 - a - b], dim=-1)


def surface_voxels(tri: torch.Tensor, resolution: int) -> torch.Tensor:
    """Flat indices of the voxels touched by triangles ``tri (T, 3, 3)`` given in continuous voxel coordinates."""
    edges = torch.stack([tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 1], tri[:, 0] - tri[:, 2]], dim=1)
    longest = edges.norm(dim=-1).max(dim=1).values  # voxels
    bucket = _bucket(torch.ceil(2.0 * longest).clamp_(min=1), _SUBDIVISIONS)
    out = []
    for b in torch.unique(bucket).tolist():
        sel = tri[bucket == b]
        w = _lattice(_SUBDIVISIONS[b], tri.device, tri.dtype)  # (M, 3)
        pts = torch.einsum("mk,tkc->tmc", w, sel).reshape(-1, 3)
        # every triangle point lies within (sub-edge) / sqrt(3) <= 0.29 voxel of a lattice point: the corners of a
        # cube of half-size 0.3 voxel about each lattice point reach every voxel that point's neighbourhood touches
        ijk = (pts[:, None, :] + _CORNERS.to(pts)).floor().long().reshape(-1, 3)
        ok = ((ijk >= 0) & (ijk < resolution)).all(dim=-1)
        ijk = ijk[ok]
        out.append((ijk[:, 0] * resolution + ijk[:, 1]) * resolution + ijk[:, 2])
    return torch.cat(out) if out else torch.zeros(0, dtype=torch.long, device=tri.device)


def _edge(p: torch.Tensor, q: torch.Tensor, px: torch.Tensor, py: torch.Tensor) -> torch.Tensor:
    """2D edge function ``cross(q - p, x - p)`` of edges ``p, q (T, 3)`` at points ``px, py (T, w, w)``."""
    return ((q[:, 0, None, None] - p[:, 0, None, None]) * (py - p[:, 1, None, None])
            - (q[:, 1, None, None] - p[:, 1, None, None]) * (px - p[:, 0, None, None]))


def solid_voxels(tri: torch.Tensor, resolution: int) -> torch.Tensor:
    """``(R, R, R)`` bool interior of a closed mesh ``tri (T, 3, 3)`` (continuous voxel coordinates), by ray
    parity along +z through every column."""
    r = resolution
    dev = tri.device
    jx, jy = _JITTER
    a, b, c = tri[:, 0], tri[:, 1], tri[:, 2]
    area = (b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0])
    keep = area.abs() > 1e-12  # triangles seen edge-on from +z cross no column
    a, b, c, area = a[keep], b[keep], c[keep], area[keep]
    xy = torch.stack([a[:, :2], b[:, :2], c[:, :2]], dim=1)
    # columns i whose ray x = i + 0.5 + jx lies in [xmin, xmax]
    i0 = torch.ceil(xy[..., 0].min(dim=1).values - 0.5 - jx).long()
    i1 = torch.floor(xy[..., 0].max(dim=1).values - 0.5 - jx).long()
    j0 = torch.ceil(xy[..., 1].min(dim=1).values - 0.5 - jy).long()
    j1 = torch.floor(xy[..., 1].max(dim=1).values - 0.5 - jy).long()
    span = torch.maximum(i1 - i0, j1 - j0) + 1
    has = span > 0
    hist = torch.zeros(r * r * (r + 1), dtype=torch.int32, device=dev)
    bucket = _bucket(span.clamp(min=1).to(torch.float64), _WINDOWS)
    for bk in torch.unique(bucket[has]).tolist():
        m = has & (bucket == bk)
        w = _WINDOWS[bk]
        d = torch.arange(w, device=dev)
        ci = (i0[m][:, None, None] + d[None, :, None]).expand(-1, w, w)  # (T, w, w)
        cj = (j0[m][:, None, None] + d[None, None, :]).expand(-1, w, w)
        px = ci.to(tri.dtype) + 0.5 + jx
        py = cj.to(tri.dtype) + 0.5 + jy
        am, bm, cm, ar = a[m], b[m], c[m], area[m]

        w0, w1, w2 = (_edge(p, q, px, py) for p, q in ((bm, cm), (cm, am), (am, bm)))  # barycentric * area
        sgn = torch.sign(ar)[:, None, None]
        inside = (w0 * sgn >= 0) & (w1 * sgn >= 0) & (w2 * sgn >= 0)
        inside &= (ci >= 0) & (ci < r) & (cj >= 0) & (cj < r)
        inside &= (ci <= i1[m][:, None, None]) & (cj <= j1[m][:, None, None])
        z = (w0 * am[:, 2, None, None] + w1 * bm[:, 2, None, None] + w2 * cm[:, 2, None, None]) / ar[:, None, None]
        kz = torch.ceil(z - 0.5).clamp_(0, r).long()  # first voxel centre above the crossing (r: above all)
        flat = ((ci * r + cj) * (r + 1) + kz)[inside]
        hist.index_add_(0, flat, torch.ones_like(flat, dtype=torch.int32))
    parity = torch.cumsum(hist.view(r, r, r + 1), dim=2)[..., :r] % 2
    return parity.bool()


def voxelize(vertices: torch.Tensor, faces: torch.Tensor, grid: VoxelGrid, solid: bool = False) -> torch.Tensor:
    """Opacity ``(R, R, R)`` float32 (``[x, y, z]``) of the mesh ``vertices (V, 3)``, ``faces (T, 3)`` in
    ``grid``: its surface voxels, plus (``solid=True``, closed meshes only) the voxels inside it."""
    check_positions(vertices)
    check_shape(faces, "T 3", name="faces")
    check(faces.shape[0] > 0, f"faces must have shape (T, 3) with T > 0, got {tuple(faces.shape)}")
    check(int(faces.min()) >= 0 and int(faces.max()) < vertices.shape[0],
          f"faces index vertices outside [0, {vertices.shape[0]})")
    r = grid.resolution
    tri = grid.to_voxel(vertices.to(torch.float32))[faces.long()]  # (T, 3, 3)
    occ = torch.zeros(r * r * r, dtype=torch.float32, device=vertices.device)
    occ[surface_voxels(tri, r)] = 1.0
    occ = occ.view(r, r, r)
    if solid:
        occ = torch.maximum(occ, solid_voxels(tri.to(torch.float64), r).to(torch.float32))
    return occ

"""Global-frame diffuse transfer and its interreflection bounces (seed 000, section 3 and Fig. 7).

Direct transfer of a vertex with normal ``n`` (docs/DESIGN.md, "Diffuse transfer")::

    t0 = int V(w) max(n.w, 0) / pi * y(w) dw            (world frame, order ``transfer_order``)

so that a Lambertian surface of albedo ``rho`` under distant lighting ``L`` (SH) has exit
radiance ``rho * (L . t)``. With the bake's hemisphere rays (solid angle ``2 pi / R`` each) the
estimate is ``t0 = sum_r V_r (2 cos_r / R) y(w_r)``.

Bounce ``b`` gathers, along every *occluded* ray, the exit radiance of the surface it hits,
interpolated from the hit triangle's vertices with the hit's barycentrics::

    t_b(p) = sum_{r occluded} (2 cos_r / R) * rho * t_{b-1}(hit(p, r))

which is linear in ``t_{b-1}``: ``t_b = M @ t_{b-1}`` with a sparse ``(V, V)`` gather operator
``M`` assembled once per frame. The baked transfer is ``t0 + t1 + ... + t_B``.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from prt_torch.bake.directions import rotated_frames, world_directions
from prt_torch.sh.basis import sh_basis

#: rays per SH evaluation block in :func:`direct_transfer` (bounds the (rays, C) temporary)
_SUB_RAYS = 1 << 16


def direct_transfer(visible: np.ndarray, cos_local: np.ndarray, world_dirs: np.ndarray, order: int) -> np.ndarray:
    """Cosine-weighted world-frame transfer of a block of vertices.

    Args:
        visible: ``(R, V)`` float32 0/1 ray visibility.
        cos_local: ``(R,)`` float32 ``n . w_r`` (the local ``z`` of each hemisphere direction).
        world_dirs: ``(R, V, 3)`` float32 unit world directions of the rays.
        order: SH order ``n`` of the transfer (``C = n*n``).

    Returns:
        ``(V, C)`` float32.
    """
    R, V = visible.shape
    C = order * order
    w = (visible * (cos_local * (2.0 / R))[:, None]).astype(np.float32)  # (R, V)
    out = np.zeros((V, C), dtype=np.float32)
    # walk blocks of whole vertices so that each block is a contiguous (R, Vb, 3) slab per ray row
    vb = max(1, _SUB_RAYS // max(R, 1))
    for v0 in range(0, V, vb):
        v1 = min(V, v0 + vb)
        Y = sh_basis(world_dirs[:, v0:v1], order, check=False)  # (R, Vb, C)
        out[v0:v1] = np.einsum("rv,rvc->vc", w[:, v0:v1], Y, optimize=True)
    return out


def occlusion_transfer(frames: np.ndarray, local_dirs: np.ndarray, phi: np.ndarray, occluded: np.ndarray,
                       cos_weight: np.ndarray, order: int) -> np.ndarray:
    """:func:`direct_transfer` of a whole frame from its stored ray occlusion (the bake's hits, kept after tracing).

    The world directions are re-formed from the vertex frames block by block (the bake's rays:
    ``local_dirs (R, 3)`` hemisphere directions, each vertex's rotation ``phi (V,)`` about its normal), so no
    ``(R, V, 3)`` array of the whole frame is built. ``frames (V, 3, 3)``, ``occluded (R, V)`` bool,
    ``cos_weight (R,)`` the per-ray weight :func:`direct_transfer` takes as ``cos_local``. Returns ``(V, C)`` float32.
    """
    V = frames.shape[0]
    R = occluded.shape[0]
    f32 = np.asarray(frames).astype(np.float32, copy=False)
    out = np.empty((V, order * order), dtype=np.float32)
    vb = max(1, _SUB_RAYS // max(R, 1))
    for v0 in range(0, V, vb):
        v1 = min(V, v0 + vb)
        dirs = world_directions(local_dirs, rotated_frames(f32[v0:v1], phi[v0:v1]))
        out[v0:v1] = direct_transfer(np.logical_not(occluded[:, v0:v1]).astype(np.float32), cos_weight, dirs, order)
    return out


def gather_entries(
    vertex_ids: np.ndarray, ray_cos: np.ndarray, prim: np.ndarray, u: np.ndarray, v: np.ndarray, faces: np.ndarray,
    n_rays: int, albedo: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """COO entries ``(rows, cols, vals)`` of the bounce operator for a set of occluded rays.

    Args:
        vertex_ids: ``(H,)`` the vertex that shot each occluded ray.
        ray_cos: ``(H,)`` ``n . w`` of each ray.
        prim, u, v: ``(H,)`` hit triangle and Embree barycentrics (hit = ``(1-u-v) p0 + u p1 + v p2``).
        faces: ``(T, 3)`` triangles.
        n_rays: rays per vertex ``R``.
        albedo: diffuse albedo ``rho``.
    """
    wgt = (2.0 * albedo / n_rays) * ray_cos.astype(np.float64)
    tri = faces[prim]  # (H, 3)
    bary = np.stack([1.0 - u - v, u, v], axis=1).astype(np.float64)
    rows = np.repeat(vertex_ids.astype(np.int64), 3)
    return rows, tri.reshape(-1).astype(np.int64), (bary * wgt[:, None]).reshape(-1)


def bounce_operator(
    entries: list[tuple[np.ndarray, np.ndarray, np.ndarray]], n_vertices: int
) -> sp.csr_matrix:
    """Sum COO entries (from :func:`gather_entries`) into the ``(V, V)`` CSR gather operator ``M``."""
    if entries:
        rows = np.concatenate([e[0] for e in entries])
        cols = np.concatenate([e[1] for e in entries])
        vals = np.concatenate([e[2] for e in entries])
    else:
        rows = cols = np.zeros(0, dtype=np.int64)
        vals = np.zeros(0)
    return sp.coo_matrix((vals, (rows, cols)), shape=(n_vertices, n_vertices)).tocsr()


def interreflect(direct: np.ndarray, operator: sp.csr_matrix, bounces: int) -> np.ndarray:
    """``t0 + M t0 + M^2 t0 + ...`` (``bounces`` terms after the direct one); ``(V, C)`` float32."""
    total = direct.astype(np.float64)
    t = total
    for _ in range(bounces):
        t = operator @ t
        total = total + t
    return total.astype(np.float32)

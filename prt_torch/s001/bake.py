"""Glossy transfer matrices per vertex (seed 001 eq. 5, after Sloan et al. 2002), from the bake's own rays.

A vertex with frame ``F`` (rows ``t, b, n``) and distant lighting ``L`` (global SH, ``C = n*n``) receives the
transferred incident radiance ``l_local = T @ L`` (local-frame SH, ``C``)::

    T_ij = int V(w) y_i(F w) y_j(w) dw                                   (shadowed direct light)
         + sum_{r occluded} dw_r y_i(F w_r) rho t_hit(r)_j                (diffuse interreflection)
         + k_i s_j                                                        (subsurface exit term, optional)

* **Rays**: the bake's hemisphere rays (:mod:`prt_torch.bake.directions`), each of solid angle
  ``dw_r = 2 pi / R``; ray ``r`` of vertex ``v`` has local direction ``Rz(phi_v) d_r``, so
  ``y(F w_r) = D_z(phi_v) y(d_r)``: the sum over rays is ONE matrix product with the shared ``(C, R)`` table
  per block of vertices, followed by the cheap SH rotation about ``z`` of the row index (as the visibility).
* **Below the horizon** (``bake.below_horizon``, recorded in the store): ``"zero"``: no light arrives from
  below the horizon, ``T`` holds the upper hemisphere only (an unoccluded vertex has
  ``T_ij = int_H y_i(F w) y_j(w) dw``, the SH rotation restricted to the upper hemisphere); ``"one"``: the
  lower hemisphere is unoccluded (seed 003 eq. 1's convention), ``T = D(F) - sum_{r occluded} dw_r y(F w_r)
  y(w_r)^T + bounces``, with ``D(F)`` the SH rotation matrix of the frame (:func:`prt_torch.sh.rotation.
  sh_rotation`; an unoccluded vertex's ``T`` is ``D(F)`` itself).
* **Interreflection** (``matrix_bounces`` = ``B``): every occluded ray gathers the diffuse exit radiance of the
  surface it hits, ``rho (L . t_hit)``, with ``t`` the global diffuse transfer of order ``n`` with ``B - 1``
  bounces (:mod:`prt_torch.bake.transfer`: direct ``t0`` plus ``B - 1`` applications of the sparse gather
  operator ``M`` built from the same hits), interpolated with the hit's barycentrics. ``T`` then holds ``B``
  bounces: the light that reached the hit point after ``B - 1`` bounces, reflected once more.
  For a Lambertian receiver, the ``(l=1, m=0)`` row of ``T`` times ``sqrt(4 pi / 3) / pi`` is exactly the
  bake's diffuse transfer with ``B`` bounces (``"zero"``): ``y_10 sqrt(4 pi/3) / pi = cos / pi`` on the rays.
* **Subsurface** (``bake.subsurface``): the subsurface exit radiance ``s . L`` (isotropic,
  :mod:`prt_torch.bake.subsurface`) enters ``T`` as the uniform incident radiance over the upper hemisphere
  that a white Lambertian surface reflects as exactly ``s . L``: ``k = h / (c . h)`` with ``h`` the local SH
  of the upper-hemisphere indicator and ``c`` those of ``max(cos, 0) / pi`` (so ``c . k = 1`` and the
  Lambertian BRDF matrix, :func:`prt_torch.s001.brdf_matrix.brdf_matrix`, gives ``y(wo)^T B k = 1``). A BRDF
  matrix of another BRDF weights the term by its response to uniform light (its albedo, up to truncation).

numpy only, float32 results; no Python loop over vertices or rays.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from functools import lru_cache
from typing import Any

import numpy as np

from prt_torch.bake.directions import hemisphere_set, rotated_frames, world_directions
from prt_torch.bake.extras import ArraySpec, BakeExtra, TracedFrame
from prt_torch.bake.trace import RayHits, RaySet, check_below_horizon
from prt_torch.bake.transfer import bounce_operator, gather_entries, interreflect, occlusion_transfer
from prt_torch.bake.visibility import projection_table, rotate_sh_z
from prt_torch.errors import PrtError
from prt_torch.sh.basis import check_order, sh_basis
from prt_torch.sh.rotation import sh_rotation
from prt_torch.sh.zonal import clamped_cosine_zh, hemisphere_zh, zh_to_sh
from prt_torch.shapes import check_shape

#: rays per SH evaluation block (bounds the (rays, Vb, C) temporaries)
_SUB_RAYS = 1 << 16
#: highest matrix order (C = 64: 16 KiB per vertex and frame)
MAX_MATRIX_ORDER = 8


@lru_cache(maxsize=8)
def matrix_table(n_rays: int, order: int) -> np.ndarray:
    """``(C, R)`` float32 ``y_i(d_r) 2 pi / R`` of the bake's ``n_rays`` hemisphere directions (read-only)."""
    t = projection_table(hemisphere_set(int(n_rays)), order)
    t.setflags(write=False)
    return t


@lru_cache(maxsize=8)
def exit_term_rows(order: int) -> np.ndarray:
    """``(C,)`` float64 ``k = h / (c . h)``: the local SH of the uniform upper-hemisphere radiance that a white
    Lambertian surface reflects as radiance 1 (see the module docstring)."""
    z = np.array([0.0, 0.0, 1.0])
    h = zh_to_sh(hemisphere_zh(order), z)
    c = zh_to_sh(clamped_cosine_zh(order), z) / math.pi
    k = h / float(c @ h)
    k.setflags(write=False)
    return k


def _check(frames: np.ndarray, hits: RayHits, rays: RaySet, faces: np.ndarray, order: int, bounces: int,
           albedo: float) -> None:
    check_order(order, MAX_MATRIX_ORDER)
    V = frames.shape[0] if frames.ndim == 3 else -1
    check_shape(frames, "V 3 3", name="frames")
    if not isinstance(hits, RayHits):
        raise PrtError(f"transfer matrices need the frame's ray hits (trace_frame keep_hits=True), got "
                       f"{type(hits).__name__}")
    check_shape(hits.prim, (rays.n_rays, V), name="ray hits (rays, vertices)")
    if rays.phi.shape != (V,):
        raise PrtError(f"ray set was made for {rays.phi.shape[0]} vertices, frames have {V}")
    if not isinstance(bounces, int | np.integer) or not 0 <= bounces <= 2:
        raise PrtError(f"matrix_bounces must be 0, 1 or 2, got {bounces!r}")
    if not 0 < albedo < 1:
        raise PrtError(f"interreflection albedo must be in (0, 1), got {albedo}")
    if bounces:
        check_shape(faces, "T 3", name="faces")


def hit_diffuse_transfer(frames: np.ndarray, hits: RayHits, rays: RaySet, faces: np.ndarray, order: int,
                         bounces: int, albedo: float) -> np.ndarray:
    """Global diffuse transfer ``t0 + M t0 + ... + M^bounces t0`` of order ``order`` from a frame's ray hits.

    The same estimate as :func:`prt_torch.bake.trace.trace_frame`'s transfer (same rays, same gather
    operator, :mod:`prt_torch.bake.transfer`), at the matrix order. ``(V, C)`` float32.
    """
    V = frames.shape[0]
    R = rays.n_rays
    occ = hits.occluded
    t0 = occlusion_transfer(frames, rays.local, rays.phi, occ, rays.cos, order)
    if not bounces:
        return t0
    idx = np.flatnonzero(occ)  # ray-major over (R, V)
    r_idx, v_idx = np.divmod(idx, V)
    entries = [gather_entries(v_idx, rays.cos[r_idx], hits.prim.reshape(-1)[idx], hits.u.reshape(-1)[idx],
                              hits.v.reshape(-1)[idx], np.asarray(faces), R, albedo)]
    return interreflect(t0, bounce_operator(entries, V), bounces)


def transfer_matrices(
    frames: np.ndarray,
    hits: RayHits,
    rays: RaySet,
    faces: np.ndarray,
    order: int = 4,
    bounces: int = 1,
    albedo: float = 0.6,
    exit_transfer: np.ndarray | None = None,
) -> np.ndarray:
    """Per-vertex transfer matrices ``T (V, C, C)`` float32 of one posed frame (see the module docstring).

    Args:
        frames: ``(V, 3, 3)`` vertex frames, rows ``(t, b, n)``, right-handed (as traced).
        hits: the frame's ray hits (:func:`prt_torch.bake.trace.trace_frame` with ``keep_hits=True``).
        rays: the bake's :class:`RaySet` (its ``below_horizon`` convention applies).
        faces: ``(T, 3)`` triangles of the traced mesh (for the bounce gather).
        order: SH order ``n`` of the matrices (``C = n*n``), 1..8.
        bounces: diffuse interreflection bounces, 0..2.
        albedo: diffuse albedo ``rho`` of the surfaces the bounces gather from.
        exit_transfer: optional ``(V, C')`` global isotropic exit-radiance transfer (subsurface, ``C' >= C``
            coefficients; the first ``C`` are used), added as the rank-1 term ``k s^T``.

    Returns:
        ``(V, C, C)`` float32: ``l_local = T[v] @ L`` (local SH of the incident radiance at vertex ``v``).
    """
    frames = np.asarray(frames)
    faces = np.asarray(faces)
    _check(frames, hits, rays, faces, order, bounces, albedo)
    one = check_below_horizon(rays.below_horizon) == "one"
    V = frames.shape[0]
    R = rays.n_rays
    C = order * order
    table = matrix_table(R, order)
    f32 = frames.astype(np.float32, copy=False)
    occ = hits.occluded
    t_prev = hit_diffuse_transfer(frames, hits, rays, faces, order, bounces - 1, albedo) if bounces else None
    out = np.empty((V, C, C), dtype=np.float32)
    vb = max(1, _SUB_RAYS // R)
    for v0 in range(0, V, vb):
        v1 = min(V, v0 + vb)
        dirs = world_directions(rays.local, rotated_frames(f32[v0:v1], rays.phi[v0:v1]))  # (R, n, 3)
        Y = sh_basis(dirs, order, check=False)  # (R, n, C) y(w_r)
        o = occ[:, v0:v1]
        # "one": D(F) minus the occluded rays' direct light; "zero": the escaping rays' direct light
        W = Y * (-o.astype(np.float32) if one else np.logical_not(o).astype(np.float32))[..., None]
        if t_prev is not None:
            r_i, v_i = np.nonzero(o)
            prim = hits.prim[:, v0:v1][r_i, v_i]
            u = hits.u[:, v0:v1][r_i, v_i]
            w = hits.v[:, v0:v1][r_i, v_i]
            bary = np.stack([1.0 - u - w, u, w], axis=1).astype(np.float32)  # (H, 3)
            t_hit = np.einsum("hk,hkc->hc", bary, t_prev[faces[prim]])  # (H, C)
            W[r_i, v_i] += np.float32(albedo) * t_hit
        # ONE GEMM: (C, R) x (R, n*C) -> rows in each vertex's rotated frame, then rotate them about z
        Tb = np.tensordot(table, W, axes=(1, 0)).transpose(1, 0, 2)  # (n, C_i, C_j)
        Tb = rotate_sh_z(np.ascontiguousarray(Tb.transpose(0, 2, 1)), rays.phi[v0:v1, None]).transpose(0, 2, 1)
        out[v0:v1] = Tb
    if one:
        out += sh_rotation(frames.astype(np.float64), order, check=False).astype(np.float32)
    if exit_transfer is not None:
        s = np.asarray(exit_transfer)
        if s.ndim != 2 or s.shape[0] != V or s.shape[1] < C:
            raise PrtError(f"exit transfer must have shape ({V}, >= {C}), got {s.shape}")
        out += (exit_term_rows(order).astype(np.float32)[None, :, None] * s[:, None, :C].astype(np.float32))
    return out


def matrix_arrays(params: Mapping[str, Any], n_vertices: int) -> ArraySpec:
    """The array seed 001 adds to a bake (:class:`prt_torch.bake.extras.BakeExtra`): ``transfer_matrix`` of
    per-frame shape ``(V, C, C)`` float32 (``C = matrix_order**2``) when ``params["transfer_matrix"]`` is set
    (``params``: the store's ``attrs["bake"]``), else nothing."""
    if not params.get("transfer_matrix"):
        return {}
    c = int(params["matrix_order"]) ** 2
    return {"transfer_matrix": ((n_vertices, c, c), "float32")}


def frame_matrices(params: Mapping[str, Any], frame: TracedFrame) -> dict[str, np.ndarray]:
    """``{"transfer_matrix": (V, C, C) float32}`` of one traced frame (:func:`transfer_matrices` of its ray hits,
    ``matrix_order``, ``matrix_bounces`` and ``albedo`` from ``params``, the frame's ``subsurface`` as the exit
    term when the bake has one)."""
    hits = frame.result.hits
    if hits is None:
        raise PrtError("transfer matrices need the frame's ray hits (trace_frame keep_hits=True)")
    return {"transfer_matrix": transfer_matrices(frame.frames, hits, frame.rays, frame.faces,
                                                 order=int(params["matrix_order"]),
                                                 bounces=int(params["matrix_bounces"]),
                                                 albedo=float(params["albedo"]),
                                                 exit_transfer=frame.arrays.get("subsurface"))}


#: seed 001's entry of :data:`prt_torch.bake.extras.BAKE_EXTRAS`: per-vertex transfer matrices from the bake's rays
TRANSFER_MATRICES = BakeExtra(arrays=matrix_arrays, compute=frame_matrices, needs_hits=True)

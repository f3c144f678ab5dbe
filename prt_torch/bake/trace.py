"""Bake one posed frame: trace every vertex's hemisphere rays and project them to SH.

The per-frame hot path, vectorised over blocks of vertices (no Python loop over vertices or
rays): one float32 matmul builds a block's ``(R, Vb, 3)`` world ray directions, one Embree
call traces them, one matmul projects the ``(R, Vb)`` visibility to SH.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from prt_torch.bake.directions import hemisphere_set, rotated_frames, vertex_angles, world_directions
from prt_torch.bake.embree import RayScene
from prt_torch.bake.transfer import bounce_operator, direct_transfer, gather_entries, interreflect
from prt_torch.bake.visibility import project_visibility, projection_table
from prt_torch.conventions import BELOW_HORIZON
from prt_torch.errors import PrtError
from prt_torch.shapes import check_shape


def check_below_horizon(value: object) -> str:
    """``value`` if it is a :data:`BELOW_HORIZON` convention, else a one-line :class:`PrtError`."""
    if value not in BELOW_HORIZON:
        raise PrtError(f"below_horizon must be one of {list(BELOW_HORIZON)}, got {value!r}")
    return str(value)


@dataclass(frozen=True)
class RaySet:
    """Everything about the rays that does not change from frame to frame.

    Attributes:
        local: ``(R, 3)`` float32 hemisphere directions in the (unrotated) local frame, ``z >= 0``.
        cos: ``(R,)`` float32 their ``z`` (``n . w``).
        table: ``(C, R)`` float32 projection table ``y(d_r) 2 pi / R``.
        phi: ``(V,)`` float64 fixed per-vertex rotation angles about the normal.
        order: SH order of the visibility.
        below_horizon: the visibility below the horizon, ``"zero"`` or ``"one"`` (:data:`BELOW_HORIZON`).
    """

    local: np.ndarray
    cos: np.ndarray
    table: np.ndarray
    phi: np.ndarray
    order: int
    below_horizon: str = "zero"

    @classmethod
    def make(cls, n_rays: int, order: int, n_vertices: int, seed: int, below_horizon: str = "zero") -> RaySet:
        """The ray set of a bake: ``n_rays`` hemisphere directions, order-``order`` table, seeded angles."""
        below_horizon = check_below_horizon(below_horizon)
        local64 = hemisphere_set(n_rays)
        local = local64.astype(np.float32)
        return cls(local=local, cos=np.ascontiguousarray(local[:, 2]), table=projection_table(local64, order),
                   phi=vertex_angles(n_vertices, seed), order=order, below_horizon=below_horizon)

    @property
    def n_rays(self) -> int:
        return int(self.local.shape[0])


@dataclass(frozen=True)
class RayHits:
    """The first hit of every bake ray of a frame (``keep_hits=True``), for passes that reuse the same rays
    (transfer matrices, subsurface). Ray ``r`` of vertex ``v`` is ``rays.local[r]`` turned by ``rays.phi[v]``
    about the normal and expressed in the world through the frame (:func:`world_directions`).

    Attributes:
        prim: ``(R, V)`` int32 hit triangle, -1 where the ray escapes.
        u, v: ``(R, V)`` float32 Embree barycentrics of the hit (hit = ``(1-u-v) p0 + u p1 + v p2``).
    """

    prim: np.ndarray
    u: np.ndarray
    v: np.ndarray

    @property
    def occluded(self) -> np.ndarray:
        """``(R, V)`` bool, True where the ray hits the mesh."""
        return self.prim != -1


@dataclass
class FrameResult:
    """``visibility (V, C)`` float32 local frame; ``transfer (V, C6)`` float32 world frame or None;
    ``hits``: every ray's first hit when traced with ``keep_hits=True``, else None."""

    visibility: np.ndarray
    transfer: np.ndarray | None
    n_rays: int
    hits: RayHits | None = None


def trace_frame(
    positions: np.ndarray,
    frames: np.ndarray,
    faces: np.ndarray,
    rays: RaySet,
    offset: float,
    transfer_order: int | None = None,
    bounces: int = 0,
    albedo: float = 0.6,
    max_rays: int = 1 << 20,
    scene: RayScene | None = None,
    keep_hits: bool = False,
) -> FrameResult:
    """Ground-truth visibility (and optionally transfer) of one posed mesh.

    Args:
        positions: ``(V, 3)`` posed vertex positions, world.
        frames: ``(V, 3, 3)`` vertex frames, rows ``(t, b, n)`` (``n`` the smooth normal).
        faces: ``(T, 3)`` triangles.
        rays: the frame-invariant :class:`RaySet` (its ``phi`` has ``V`` entries; its ``below_horizon``
            sets the visibility below the horizon, see the module docstring).
        offset: ray origins are ``positions + offset * n`` (world units).
        transfer_order: also compute cosine-weighted world-frame transfer of this order.
        bounces: interreflection bounces added to the transfer (needs ``transfer_order``).
        albedo: diffuse albedo of the interreflection.
        max_rays: rays per Embree call (memory bound).
        scene: trace against this scene instead of the mesh ``(positions, faces)``; ``positions``
            are then arbitrary sample points with frames (no bounces: they gather mesh vertices).
        keep_hits: also return every ray's first hit (:class:`RayHits`; rays are then traced with Embree's
            intersect, as with bounces, instead of its occlusion query).
    """
    positions = np.asarray(positions)
    frames = np.asarray(frames)
    V = positions.shape[0]
    check_shape(positions, "V 3", name="positions")
    check_shape(frames, (V, 3, 3), name="frames")
    if not np.isfinite(positions).all():
        raise PrtError("posed positions contain NaN or Inf")
    if not np.isfinite(frames).all():
        raise PrtError("vertex frames contain NaN or Inf")
    if rays.phi.shape != (V,):
        raise PrtError(f"ray set was made for {rays.phi.shape[0]} vertices, mesh has {V}")
    if bounces and not transfer_order:
        raise PrtError("interreflection bounces need transfer (set transfer: true)")
    if bounces and scene is not None:
        raise PrtError("interreflection bounces need the scene to be the baked mesh itself")

    if scene is None:
        scene = RayScene(positions, faces)
    R = rays.n_rays
    f32 = frames.astype(np.float32, copy=False)
    origins_all = (positions + offset * frames[:, 2]).astype(np.float32)
    vis = np.empty((V, rays.table.shape[0]), dtype=np.float32)
    one = check_below_horizon(rays.below_horizon) == "one"
    if one:
        constant = np.zeros(rays.table.shape[0], dtype=np.float32)
        constant[0] = np.float32(np.sqrt(4.0 * np.pi))  # SH of V = 1 on the whole sphere
    tr = np.empty((V, transfer_order * transfer_order), dtype=np.float32) if transfer_order else None
    entries = []
    if keep_hits:
        hit_prim = np.empty((R, V), dtype=np.int32)
        hit_u = np.empty((R, V), dtype=np.float32)
        hit_v = np.empty((R, V), dtype=np.float32)
    vb = max(1, max_rays // R)
    for v0 in range(0, V, vb):
        v1 = min(V, v0 + vb)
        n = v1 - v0
        dirs = world_directions(rays.local, rotated_frames(f32[v0:v1], rays.phi[v0:v1]))  # (R, n, 3)
        origins = np.empty((R, n, 3), dtype=np.float32)
        origins[:] = origins_all[v0:v1]
        if bounces or keep_hits:
            hits = scene.intersect(origins.reshape(-1, 3), dirs.reshape(-1, 3))
            occluded = hits.prim != -1
            if keep_hits:
                hit_prim[:, v0:v1] = hits.prim.reshape(R, n)
                hit_u[:, v0:v1] = hits.u.reshape(R, n)
                hit_v[:, v0:v1] = hits.v.reshape(R, n)
        else:
            occluded = scene.occluded(origins.reshape(-1, 3), dirs.reshape(-1, 3))
        visible = np.logical_not(occluded).reshape(R, n).astype(np.float32)
        if one:  # 1 - occluded: the lower hemisphere in closed form, only the occluded rays projected
            vis[v0:v1] = constant - project_visibility(occluded.reshape(R, n).astype(np.float32), rays.table,
                                                       rays.phi[v0:v1])
        else:
            vis[v0:v1] = project_visibility(visible, rays.table, rays.phi[v0:v1])
        if tr is not None:
            tr[v0:v1] = direct_transfer(visible, rays.cos, dirs, transfer_order)
        if bounces:
            idx = np.flatnonzero(occluded)
            r_idx, v_idx = np.divmod(idx, n)
            entries.append(gather_entries(v0 + v_idx, rays.cos[r_idx], hits.prim[idx], hits.u[idx], hits.v[idx],
                                          np.asarray(faces), R, albedo))
    if tr is not None and bounces:
        tr = interreflect(tr, bounce_operator(entries, V), bounces)
    kept = RayHits(prim=hit_prim, u=hit_u, v=hit_v) if keep_hits else None
    return FrameResult(visibility=vis, transfer=tr, n_rays=V * R, hits=kept)

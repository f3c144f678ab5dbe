"""Peak lights in a scene (issue 27): the floor's peak shadows and the characters' shadows on each other.

A peak light (:class:`prt_torch.sg.split.PeakLight`) is a uniform disc of half-angle ``a`` about a unit direction
``l`` (world, z up, towards the light) with power ``E`` (radiance x solid angle). Its visibility at a receiver is
the visible fraction of the disc in ``[0, 1]`` (docs/DESIGN.md, the rule of :func:`prt_torch.bake.peaks.
exact_peak_visibility` and :func:`prt_torch.blockers.cones.sphere_peak_visibility`).

Occluders are capsules ``(a, b, r)`` posed by the characters' skins: the learned peak capsules as they are, and a
sphere set (the blocker spheres, learned spheres) as capsules with ``a == b`` (:func:`prt_torch.blockers.capsules.
posed_blockers`), all through the one cone kernel (:func:`prt_torch.blockers.capsule_cones.
capsule_peak_visibility`, compiled in the player).

* **Floor** (:func:`floor_peak_visibility`): the floor's vertices are receivers under EVERY character's posed
  blockers at once: one call of the cone kernel with all of them, so they multiply as independent occluders and
  the horizon share enters once. A blocker that crosses the floor plane is kept whole (a ray leaving the floor
  upwards meets only its part above the plane), and a floor vertex INSIDE one (under a foot) is in its shadow for
  every peak (every upward ray leaves it through its upper part), where the kernel would ignore it. ``exact``:
  :func:`floor_exact_peak_visibility`, Embree against the merged posed meshes of every character.
* **Floor shading** (:func:`floor_peak_radiance`): Lambert, ``albedo / pi * E_p * max(l_p . z, 0) * V_p``, summed
  over the peaks (the floor's normal is ``+z``; the albedo RGB as :class:`~prt_torch.scene.ground.Ground`'s).
* **Between characters** (:func:`others_peak_visibility`): a character's own peak visibility times the fraction
  the OTHER characters' blockers leave of each disc (the kernel with the receiver's normal along the light, so that
  the horizon share, already in the character's own visibility, is not applied twice), and, with a floor, times
  the share of each disc above the floor plane (:func:`above_floor_share`: the floor as a half-space occluder, as
  :func:`prt_torch.scene.compose.halfspace_visibility` is for SH).

numpy + numba + Embree only (the torch-free player uses it).
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from prt_torch.errors import check
from prt_torch.shapes import check_shape

#: the floor's normal (world up)
UP = np.array([0.0, 0.0, 1.0])

#: a cone-capsule kernel: ``(positions (..., V, 3), normals (..., V, 3), ends_a (..., S, 3), ends_b (..., S, 3),
#: radii (S,), directions (P, 3), angular_radii (P,)) -> (..., V, P)``, float32 arrays (default
#: :func:`prt_torch.blockers.capsule_cones.capsule_peak_visibility`; the player passes its compiled one)
Kernel = Callable[..., np.ndarray]


def _kernel(kernel: Kernel | None) -> Kernel:
    if kernel is not None:
        return kernel
    from prt_torch.blockers.capsule_cones import capsule_peak_visibility

    return capsule_peak_visibility


def _peaks(directions: np.ndarray, angular_radii: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    d = np.ascontiguousarray(directions, dtype=np.float32).reshape(-1, 3)
    r = np.ascontiguousarray(angular_radii, dtype=np.float32).reshape(-1)
    check(d.shape[0] == r.shape[0], f"peaks: {d.shape[0]} directions but {r.shape[0]} angular radii")
    return d, r


def inside_capsules(positions: np.ndarray, ends_a: np.ndarray, ends_b: np.ndarray, radii: np.ndarray) -> np.ndarray:
    """``(G,)`` bool: points ``positions (G, 3)`` inside any capsule ``ends_a, ends_b (S, 3)``, ``radii (S,)``
    (strictly: the distance to the segment ``< r``; a sphere: ``a == b``). Only the points inside a capsule's
    bounding box are tested against it (a floor under a crowd: the feet's few capsules, the vertices under them)."""
    p = np.asarray(positions, dtype=np.float64)
    a = np.asarray(ends_a, dtype=np.float64)
    b = np.asarray(ends_b, dtype=np.float64)
    r = np.asarray(radii, dtype=np.float64)
    out = np.zeros(p.shape[0], dtype=bool)
    if a.shape[0] == 0 or p.shape[0] == 0:
        return out
    lo = np.minimum(a, b) - r[:, None]
    hi = np.maximum(a, b) + r[:, None]
    box = (p.min(0)[None] < hi).all(-1) & (p.max(0)[None] > lo).all(-1)  # (S,) capsules near any point at all
    if not box.any():
        return out
    a, b, r, lo, hi = a[box], b[box], r[box], lo[box], hi[box]
    near = ((p[:, None, :] > lo[None]) & (p[:, None, :] < hi[None])).all(-1)  # (G, S') in a capsule's box
    gi, si = np.nonzero(near)
    if gi.size == 0:
        return out
    w = b[si] - a[si]
    ww = (w * w).sum(-1)
    d = p[gi] - a[si]
    t = np.clip((d * w).sum(-1) / np.where(ww > 0, ww, 1.0), 0.0, 1.0)  # closest segment point
    q = d - t[:, None] * w
    out[gi[(q * q).sum(-1) < r[si] ** 2]] = True
    return out


def floor_peak_visibility(vertices: np.ndarray, ends_a: np.ndarray, ends_b: np.ndarray, radii: np.ndarray,
                          directions: np.ndarray, angular_radii: np.ndarray,
                          kernel: Kernel | None = None) -> np.ndarray:
    """``(G, P)`` float32: the visible fraction of each peak's disc at each floor vertex under capsules (module doc).

    Args:
        vertices: ``(G, 3)`` floor vertices (normal ``+z``).
        ends_a, ends_b: ``(S, 3)`` posed capsule endpoints of every character (concatenated; spheres: the centres
            twice); radii: ``(S,)`` (> 0).
        directions: ``(P, 3)`` unit peak directions; angular_radii: ``(P,)`` half-angles (radians).
        kernel: the cone kernel (:data:`Kernel`).
    """
    pos = np.ascontiguousarray(vertices, dtype=np.float32)
    check_shape(pos, "G 3", name="floor vertices")
    ea = np.ascontiguousarray(ends_a, dtype=np.float32)
    dims = check_shape(ea, "S 3", name="floor occluder endpoints a")
    eb = np.ascontiguousarray(ends_b, dtype=np.float32)
    check_shape(eb, "S 3", name="floor occluder endpoints b", dims=dims)
    rad = np.ascontiguousarray(radii, dtype=np.float32)
    check_shape(rad, "S", name="floor occluder radii", dims=dims)
    d, a = _peaks(directions, angular_radii)
    up = np.ascontiguousarray(np.broadcast_to(UP.astype(np.float32), pos.shape))
    vis = np.array(_kernel(kernel)(pos, up, ea, eb, rad, d, a), dtype=np.float32)
    vis[inside_capsules(pos, ea, eb, rad)] = 0.0
    return vis


def floor_exact_peak_visibility(vertices: np.ndarray, meshes: list[tuple[np.ndarray, np.ndarray]],
                                directions: np.ndarray, angular_radii: np.ndarray, offset: float,
                                side: int | None = None) -> np.ndarray:
    """``(G, P)`` float32: the floor's peak visibility by Embree rays (:func:`prt_torch.bake.peaks.
    exact_peak_visibility`) against the merged posed meshes ``[(vertices (V_k, 3), faces (T_k, 3))]`` of every
    character (the floor itself hides nothing above it); ``offset``: the rays' origin offset along ``+z``."""
    from prt_torch.bake.embree import RayScene
    from prt_torch.bake.peaks import DEFAULT_DISC_SIDE, exact_peak_visibility
    from prt_torch.scene.truth import merged_mesh

    pos = np.asarray(vertices, dtype=np.float64)
    check_shape(pos, "G 3", name="floor vertices")
    d, a = _peaks(directions, angular_radii)
    scene = RayScene(*merged_mesh(meshes))
    return exact_peak_visibility(pos, np.broadcast_to(UP, pos.shape), d.astype(np.float64), a.astype(np.float64),
                                 float(offset), scene=scene, side=DEFAULT_DISC_SIDE if side is None else int(side))


def floor_peak_radiance(albedo: np.ndarray, directions: np.ndarray, powers: np.ndarray,
                        visibility: np.ndarray) -> np.ndarray:
    """``(..., G, 3)`` float32 Lambert radiance of the floor from the peaks: ``sum_p albedo / pi * E_p * max(l_p . z,
    0) * V_p`` (``albedo (3,)`` RGB; ``directions (P, 3)``; ``powers (P, 3)`` RGB ``E``; ``visibility (..., G,
    P)``)."""
    d = np.asarray(directions, dtype=np.float64).reshape(-1, 3)
    e = np.asarray(powers, dtype=np.float64)
    check_shape(e, (d.shape[0], 3), name="floor peaks: powers")
    v = np.asarray(visibility, dtype=np.float64)
    check_shape(v, ("...", "G", d.shape[0]), name="floor peaks: visibility")
    cos = np.maximum(d[:, 2], 0.0)  # (P,)
    alb = np.asarray(albedo, dtype=np.float64).reshape(3)
    return ((v * cos) @ e * (alb / math.pi)).astype(np.float32)


def above_floor_share(directions: np.ndarray, angular_radii: np.ndarray) -> np.ndarray:
    """``(P,)`` float32: the share of each peak's disc above the horizontal (the floor as a half-space occluder of a
    receiver above it; 1 for a disc wholly above, 0 wholly below)."""
    from prt_torch.blockers.cones import horizon_fraction

    d, a = _peaks(directions, angular_radii)
    return np.asarray(horizon_fraction(UP[None].astype(np.float32), d, a), dtype=np.float32)[0]


def others_peak_visibility(positions: np.ndarray, ends_a: np.ndarray, ends_b: np.ndarray, radii: np.ndarray,
                           directions: np.ndarray, angular_radii: np.ndarray,
                           kernel: Kernel | None = None) -> np.ndarray:
    """``(..., V, P)`` float32: the fraction of each peak's disc that the capsules ``ends_a, ends_b (..., S, 3)``,
    ``radii (S,)`` (the OTHER characters'; spheres: the centres twice) leave at receivers ``positions (..., V, 3)``,
    with no horizon share (module doc); the constant 1 without blockers. ``kernel``: :data:`Kernel`."""
    pos = np.ascontiguousarray(positions, dtype=np.float32)
    check_shape(pos, "... V 3", name="receiver positions")
    d, a = _peaks(directions, angular_radii)
    ea = np.ascontiguousarray(ends_a, dtype=np.float32)
    eb = np.ascontiguousarray(ends_b, dtype=np.float32)
    out = np.ones((*pos.shape[:-1], d.shape[0]), dtype=np.float32)
    if ea.shape[-2] == 0:
        return out
    rad = np.ascontiguousarray(radii, dtype=np.float32)
    for p in range(d.shape[0]):  # P <= 4 peaks: the receiver's normal along each light (horizon share 1)
        along = np.ascontiguousarray(np.broadcast_to(d[p], pos.shape))
        out[..., p] = _kernel(kernel)(pos, along, ea, eb, rad, d[p:p + 1], a[p:p + 1])[..., 0]
    return out

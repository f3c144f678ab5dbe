"""Peak-light visibility per vertex by Embree rays (issue 27, ``peaks_exact``: the oracle and the training target).

A peak light is a uniform disc on the sky: the cone (spherical cap) of half-angle ``r`` (its angular radius) about a
unit direction ``l`` (world, z up). A receiver's visibility of it is the **visible fraction of the disc's solid
angle**: the share of directions of the cap along which a ray from the receiver escapes. It is a soft shadow with
the penumbra of the disc's size.

* **Samples** (:func:`disc_samples`, :func:`cap_directions`): ``n x n`` stratified points of the unit disc -- a
  jittered grid of the square (one point uniform in each cell, from ``seed``; ``seed=None``: the cell centres)
  through Shirley & Chiu's concentric map (area preserving, so the strata stay equal-area) -- then onto the cap
  equal-area: disc radius ``rho`` -> polar angle ``theta`` with ``1 - cos theta = rho^2 (1 - cos r)``, so every
  sample stands for the same solid angle and the fraction of escaping samples estimates the visible fraction with
  at most a binomial's error (stratified: less). Each receiver turns the pattern about the light's axis by its own
  angle (from ``seed``), so neighbouring receivers do not share its aliasing.
* **Horizon**: a sample direction ``w`` with ``n . w <= 0`` counts as *not visible* (no ray is shot), the rule of
  ``max(n . l, 0)`` shading: a disc the horizon cuts is seen in part (the sphere kernel,
  :func:`prt_torch.blockers.cones.sphere_peak_visibility`, uses the same rule in closed form).
* **Rays**: from ``position + offset * normal`` (the bake's origin offset, ``ray_offset_world``;
  :func:`prt_torch.bake.embree.ray_offset`) towards every above-horizon sample, Embree's occlusion query
  (:meth:`prt_torch.bake.embree.RayScene.occluded`), all ``V x P x S`` rays in calls of at most ``max_rays``.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

from prt_torch.errors import check
from prt_torch.shapes import check_shape

if TYPE_CHECKING:
    from prt_torch.bake.embree import RayScene

#: samples per disc side by default (``n x n`` = 64 rays per vertex and peak)
DEFAULT_DISC_SIDE = 8


def disc_samples(n: int, seed: int | None = 0) -> np.ndarray:
    """``(n * n, 2)`` float64 stratified points of the unit disc (module doc): the concentric map of a jittered
    ``n x n`` grid (``seed``; ``None``: the cell centres)."""
    check(isinstance(n, (int, np.integer)) and not isinstance(n, bool) and n >= 1,
          f"disc samples per side must be an integer >= 1, got {n!r}")
    i, j = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
    if seed is None:
        jitter = np.full((2, n, n), 0.5)
    else:
        jitter = np.random.default_rng(np.random.SeedSequence([int(seed) & 0xFFFFFFFF, 0xD15C])).random((2, n, n))
    u = (2 * (i + jitter[0]) / n - 1).ravel()
    v = (2 * (j + jitter[1]) / n - 1).ravel()
    first = np.abs(u) > np.abs(v)  # Shirley & Chiu 1997: the square's concentric squares -> the disc's circles
    rho = np.where(first, u, v)
    with np.errstate(divide="ignore", invalid="ignore"):
        phi = np.where(first, math.pi / 4 * (v / u), math.pi / 2 - math.pi / 4 * (u / v))
    phi = np.where(rho == 0, 0.0, phi)
    return np.stack([rho * np.cos(phi), rho * np.sin(phi)], axis=1)


def _tangents(directions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors ``(P, 3)`` completing each unit direction to a right-handed basis (Frisvad-style)."""
    helper = np.where(np.abs(directions[:, 2:3]) < 0.9, [[0.0, 0.0, 1.0]], [[1.0, 0.0, 0.0]])
    t = np.cross(helper, directions)
    t /= np.linalg.norm(t, axis=1, keepdims=True)
    return t, np.cross(directions, t)


def _cap_coordinates(radii: np.ndarray, disc: np.ndarray) -> np.ndarray:
    """``(P, S, 3)`` float64: the equal-area map of disc points ``(S, 2)`` onto caps of half-angles ``radii (P,)``,
    in each cap's frame (``z`` its axis)."""
    k = 2 * np.sin(np.asarray(radii, dtype=np.float64) / 2) ** 2  # 1 - cos r, no cancellation
    xy = np.asarray(disc, dtype=np.float64)[None]  # (1, S, 2)
    rho2k = (xy * xy).sum(-1) * k[:, None]  # (P, S): 1 - cos theta
    scale = np.sqrt(np.clip(k[:, None] * (2 - rho2k), 0.0, None))  # sin theta / rho
    return np.stack([xy[..., 0] * scale, xy[..., 1] * scale, 1 - rho2k], axis=-1)


def cap_directions(directions: np.ndarray, radii: np.ndarray, disc: np.ndarray) -> np.ndarray:
    """``(P, S, 3)`` float64 unit directions of the caps: the equal-area map of disc points (module doc).

    Args:
        directions: ``(P, 3)`` unit cap axes.
        radii: ``(P,)`` half-angles (radians).
        disc: ``(S, 2)`` points of the unit disc.
    """
    d = np.asarray(directions, dtype=np.float64)
    t, b = _tangents(d)
    return np.einsum("psk,pkj->psj", _cap_coordinates(radii, disc), np.stack([t, b, d], axis=1))


def exact_peak_visibility(positions: np.ndarray, normals: np.ndarray, directions: np.ndarray, radii: np.ndarray,
                          offset: float, faces: np.ndarray | None = None, scene: RayScene | None = None,
                          side: int = DEFAULT_DISC_SIDE, seed: int | None = 0, max_rays: int = 1 << 20) -> np.ndarray:
    """Visible fraction of each peak's disc at each receiver, by Embree rays to ``side x side`` disc samples.

    Args:
        positions: ``(V, 3)`` receiver points (posed vertices), world, z up.
        normals: ``(V, 3)`` their unit normals (ray origins ``positions + offset * normals``; the horizon).
        directions: ``(P, 3)`` unit peak directions (towards the light).
        radii: ``(P,)`` peak angular radii (half-angles, radians, in ``(0, pi/2]``).
        offset: the ray origins' offset along the normal (world units; the bake's ``ray_offset_world``).
        faces: ``(T, 3)`` triangles of the mesh ``(positions, faces)`` to trace against (without ``scene``).
        scene: trace against this scene instead (a posed mesh and a floor, several characters ...).
        side: samples per disc side (``S = side^2`` rays per receiver and peak).
        seed: the samples' jitter and the receivers' pattern angles (``None``: cell centres, no turn).
        max_rays: rays per Embree call (memory bound).

    Returns:
        ``(V, P)`` float32 in ``[0, 1]``: the share of each disc's samples above the horizon whose ray escapes.
    """
    pos = np.asarray(positions, dtype=np.float64)
    nrm = np.asarray(normals, dtype=np.float64)
    dirs = np.asarray(directions, dtype=np.float64)
    rad = np.asarray(radii, dtype=np.float64)
    dims = check_shape(pos, "V 3", name="receiver positions")
    check_shape(nrm, "V 3", name="receiver normals", dims=dims)
    check_shape(dirs, "P 3", name="peak directions", dims=dims)
    check_shape(rad, "P", name="peak angular radii", dims=dims)
    check(bool(np.isfinite(pos).all() and np.isfinite(nrm).all()), "receiver positions or normals contain NaN or Inf")
    check(bool(np.isfinite(dirs).all()) and bool(np.allclose(np.linalg.norm(dirs, axis=1), 1.0, atol=1e-5)),
          "peak directions must be finite unit vectors")
    check(bool(np.isfinite(rad).all() and (rad > 0).all() and (rad <= math.pi / 2).all()),
          "peak angular radii must be in (0, pi/2] radians")
    check(math.isfinite(offset) and offset >= 0, f"ray offset must be finite and >= 0, got {offset}")
    check(isinstance(max_rays, int) and max_rays >= 1, f"max_rays must be an integer >= 1, got {max_rays!r}")
    check((faces is None) != (scene is None), "give exactly one of faces (the mesh to trace) and scene")
    if scene is None:
        from prt_torch.bake.embree import RayScene  # the bake extra (embreex): record_directions needs none of it

        scene = RayScene(pos, faces)  # type: ignore[arg-type]
    V, P = pos.shape[0], dirs.shape[0]
    disc = disc_samples(side, seed)
    S = disc.shape[0]
    turn = (np.zeros(V) if seed is None else
            np.random.default_rng(np.random.SeedSequence([int(seed) & 0xFFFFFFFF, 0x7E5A])).uniform(0, 2 * math.pi, V))
    local = _cap_coordinates(rad, disc).astype(np.float32)  # (P, S, 3)
    t, b = _tangents(dirs)
    origins_all = (pos + offset * nrm).astype(np.float32)
    visible = np.empty((V, P), dtype=np.float32)
    vb = max(1, max_rays // (P * S))
    for v0 in range(0, V, vb):  # memory chunks of whole receivers, one Embree call each
        v1 = min(V, v0 + vb)
        c, s = np.cos(turn[v0:v1])[:, None, None], np.sin(turn[v0:v1])[:, None, None]
        basis = np.stack([c * t + s * b, c * b - s * t, np.broadcast_to(dirs, (v1 - v0, P, 3))], axis=2)  # (n,P,3,3)
        basis = basis.astype(np.float32)  # each receiver's cap frames, turned about the axes by its angle
        n_dot = np.einsum("npkj,nj->npk", basis, nrm[v0:v1].astype(np.float32))  # n . (t, b, d)
        up = np.einsum("psk,npk->nps", local, n_dot) > 0
        idx = np.nonzero(up)
        escaped = np.zeros(up.shape, dtype=bool)
        if idx[0].size:
            w = np.einsum("rk,rkj->rj", local[idx[1], idx[2]], basis[idx[0], idx[1]])  # (N, 3) above the horizon
            escaped[idx] = ~scene.occluded(origins_all[v0:v1][idx[0]], w)
        visible[v0:v1] = escaped.mean(axis=-1, dtype=np.float64).astype(np.float32)
    return visible


# -- the bake's record (``bake.peaks``): the learned peak blockers' training data ------------------------------------


def record_directions(frame: int, count: int, min_elevation_deg: float, seed: int = 0) -> np.ndarray:
    """``(count, 3)`` float32 unit world directions (z up) of one baked frame's recorded peaks: uniform in solid
    angle over the sky above ``min_elevation_deg`` (every azimuth, so every root heading), seeded by ``(seed,
    frame)`` so that a resumed or re-baked block records the very same directions."""
    rng = np.random.default_rng(np.random.SeedSequence([int(seed) & 0xFFFFFFFF, int(frame), 0x5EA7]))
    z0 = math.sin(math.radians(float(min_elevation_deg)))
    z = z0 + (1 - z0) * rng.random(count)
    phi = 2 * math.pi * rng.random(count)
    r = np.sqrt(np.clip(1 - z * z, 0.0, None))
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1).astype(np.float32)


def record_frame(params: dict, frame: int, positions: np.ndarray, normals: np.ndarray, faces: np.ndarray,
                 offset: float, scene: RayScene | None = None) -> dict[str, np.ndarray]:
    """The ``bake.peaks`` arrays of one frame (``params`` = the recorded ``attrs["bake"]["peaks"]``):
    ``peak_directions (D, 3)`` (:func:`record_directions`, the bake's ``seed``) and ``peak_visibility (V, D)``
    float32, :func:`exact_peak_visibility` of discs of ``angular_radius_deg`` with ``disc_side^2`` rays each."""
    d = record_directions(frame, int(params["directions"]), float(params["min_elevation_deg"]),
                          int(params.get("seed", 0)))
    radii = np.full(len(d), math.radians(float(params["angular_radius_deg"])))
    vis = exact_peak_visibility(positions, normals, d.astype(np.float64), radii, offset,
                                faces=None if scene is not None else faces, scene=scene,
                                side=int(params["disc_side"]), seed=int(frame))
    return {"peak_directions": d, "peak_visibility": vis}

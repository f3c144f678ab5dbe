"""Shading SH visibility for evaluation: environment lights, a diffuse and a glossy RPO.

Shaded radiance is linear in the visibility ``v (F, V, C)`` (seed 003 eq. 11), so for each frame
we build a *shading vector* ``a (F, V, C, 3)`` once and shade any visibility (truth, each model,
no shadowing) as ``L = sum_c a[..., c, :] v[..., c]``:

* lighting ``l (C, 3)`` (world) is rotated into every local vertex frame exactly with the SH
  rotation matrices ``D(F)`` (frame rows t, b, n: a local direction is ``F @ w``, so
  ``l_local = D(F) @ l``);
* the RPO of a cosine-weighted BRDF ``f~ ~= sum_b U_b(wi) W_b(wo)`` (Kautz-McCool SVD factors,
  SH-projected ``u_b``, ``w_b``) gives ``L = sum_b (w_b . y(wo)) (l . (M(u_b) v))``, i.e.
  ``a = sum_b (w_b . y(wo)) M(u_b) l`` (``M`` the symmetric SH product matrix);
* ``lambert``: ``f = albedo/pi`` (one exact term, ``u = SH of max(z, 0) albedo/pi``, ``w = 1``);
  ``phong``: normalised Phong lobe ``(s+2)/(2 pi) max(r(wo) . wi, 0)^s`` (``k = 8`` terms).

The view is a fixed world direction toward the camera; for the glossy RPO vertices facing away
(``wo.z <= 0``) get zero radiance (the diffuse one is view-independent). Environment lights:
``uffizi`` and ``mondello`` from ``../shared/data/envmaps`` when present, a procedural CIE sky,
and procedural fallbacks so that there are always at least three.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from prt_torch.errors import check
from prt_torch.sh.basis import sh_basis
from prt_torch.sh.product import product_matrix
from prt_torch.sh.quadrature import sphere_directions
from prt_torch.sh.rotation import sh_rotation
from prt_torch.sh.zonal import clamped_cosine_zh, zh_to_sh

DEFAULT_VIEW = np.array([0.3, -1.0, 0.35]) / np.linalg.norm([0.3, -1.0, 0.35])


@dataclass
class RPO:
    """A factored cosine-weighted BRDF: ``M (k, C, C)`` product matrices of the light factors,
    ``w (k, C)`` SH of the view factors, ``name``."""

    name: str
    M: np.ndarray
    w: np.ndarray

    @property
    def order(self) -> int:
        return int(round(np.sqrt(self.M.shape[-1])))


def lambert_rpo(order: int, albedo: float = 0.8) -> RPO:
    """Diffuse: ``f~ = albedo/pi max(wi.z, 0)``, exactly one term (``W = 1``, ``w = sqrt(4 pi) e_0``)."""
    u = zh_to_sh(clamped_cosine_zh(order), np.array([0.0, 0.0, 1.0])) * albedo / np.pi
    w = np.zeros((1, order * order))
    w[0, 0] = np.sqrt(4 * np.pi)  # the constant 1 in SH
    return RPO("lambert", product_matrix(u)[None], w)


@functools.lru_cache(maxsize=8)
def phong_rpo(order: int, shininess: float = 8.0, k: int = 8, n_dirs: int = 1200) -> RPO:
    """Glossy: normalised Phong lobe about the mirror direction, cosine weighted, factored by SVD."""
    dirs, wts = sphere_directions(n_dirs, seed=0), np.full(n_dirs, 4 * np.pi / n_dirs)
    up = dirs[:, 2] > 0
    wo = dirs[up]
    r = wo * np.array([-1.0, -1.0, 1.0])  # mirror of wo about the normal +z
    lobe = (shininess + 2) / (2 * np.pi) * np.maximum(dirs @ r.T, 0.0) ** shininess  # (Nwi, Nwo)
    table = lobe * np.maximum(dirs[:, 2:3], 0.0)
    # SVD in the quadrature-weighted inner products so truncation is L2-optimal on the sphere
    sw_i, sw_o = np.sqrt(wts)[:, None], np.sqrt(wts[up])[None, :]
    u_, s, vt = np.linalg.svd(sw_i * table * sw_o, full_matrices=False)
    k = min(k, len(s))
    U = u_[:, :k] * s[:k] / sw_i  # (Nwi, k) light factors
    W = vt[:k].T / sw_o.T  # (Nwo, k) view factors
    y_i = sh_basis(dirs, order)
    u_sh = (y_i * wts[:, None]).T @ U  # (C, k)
    y_o = sh_basis(wo, order)
    w_sh = np.linalg.lstsq(y_o * np.sqrt(wts[up])[:, None], W * np.sqrt(wts[up])[:, None], rcond=None)[0]  # (C, k)
    return RPO(f"phong{shininess:g}", product_matrix(u_sh.T), w_sh.T)


def default_lights(order: int, shared_data: Path | None = None) -> dict[str, np.ndarray]:
    """At least three ``(C, 3)`` world SH lights: env maps when available, then procedural ones."""
    from prt_torch.light import directional_light_sh, envmap_to_sh, load_envmap, sky_sh

    lights: dict[str, np.ndarray] = {}
    if shared_data is not None:
        for name, fname in (("uffizi", "uffizi.hdr"), ("mondello", "spiaggia_di_mondello_1k.hdr")):
            p = Path(shared_data) / "envmaps" / fname
            if p.is_file():
                lights[name] = envmap_to_sh(load_envmap(p), order)
    lights["sky"] = sky_sh(order)
    if len(lights) < 3:
        amb = np.zeros((order * order, 3))
        amb[0] = np.sqrt(4 * np.pi) * 0.3
        lights["key_fill"] = (directional_light_sh(np.array([0.6, -0.5, 0.62]) / np.linalg.norm([0.6, -0.5, 0.62]),
                                                   (3.0, 2.8, 2.5), order, half_angle=0.3) + amb)
    if len(lights) < 3:
        lights["side"] = directional_light_sh(np.array([-0.8, 0.2, 0.57]) / np.linalg.norm([-0.8, 0.2, 0.57]),
                                              (2.0, 2.2, 2.6), order, half_angle=0.5)
    return lights


def shading_set(frames: np.ndarray, lights: dict[str, np.ndarray], rpos: dict[str, RPO],
                view: np.ndarray = DEFAULT_VIEW, chunk: int = 16384) -> dict[str, np.ndarray]:
    """Shading vectors ``{"<light>/<rpo>": a (F, V, C, 3) float32}`` with radiance
    ``L = einsum('fvc,fvcr->fvr', v, a)``; the SH rotations ``D(F)`` are computed once per chunk
    of vertices and shared by every light and RPO.

    ``frames (F, V, 3, 3)`` local frames (rows t, b, n, world), lights ``(C, 3)`` world SH.
    """
    frames = np.asarray(frames, dtype=np.float64)
    check(frames.ndim == 4 and frames.shape[2:] == (3, 3), f"frames: expected (F, V, 3, 3), got {frames.shape}")
    check(bool(np.isfinite(frames).all()), "frames contain NaN or Inf")
    order = next(iter(rpos.values())).order
    c = order * order
    for name, light in lights.items():
        check(light.shape == (c, 3), f"light '{name}': expected ({c}, 3) SH for order {order}, got {light.shape}")
    f, v = frames.shape[:2]
    flat = frames.reshape(-1, 3, 3)
    out = {f"{ln}/{rn}": np.empty((f * v, c, 3), dtype=np.float32) for ln in lights for rn in rpos}
    for lo in range(0, flat.shape[0], chunk):
        hi = min(lo + chunk, flat.shape[0])
        # orthonormalise (float32 storage) so the rotation is exact
        u_, _, vt = np.linalg.svd(flat[lo:hi])
        r = u_ @ vt
        r[np.linalg.det(r) < 0] *= -1  # should not happen for right-handed frames
        d = sh_rotation(r, order, check=False)  # (n, C, C)
        wo = r @ view  # (n, 3) local view direction
        yo = sh_basis(wo / np.linalg.norm(wo, axis=1, keepdims=True), order, check=False)
        for ln, light in lights.items():
            l_local = d @ light  # (n, C, 3)
            for rn, rpo in rpos.items():
                weight = yo @ rpo.w.T  # (n, k)
                if rpo.name != "lambert":  # view-dependent: no radiance toward a camera below the surface
                    weight = weight * (wo[:, 2:3] > 0)
                mw = np.einsum("nk,kij->nij", weight, rpo.M)  # (n, C, C)
                out[f"{ln}/{rn}"][lo:hi] = mw @ l_local
    return {k: a.reshape(f, v, c, 3) for k, a in out.items()}


def shading_vectors(frames: np.ndarray, light: np.ndarray, rpo: RPO, view: np.ndarray = DEFAULT_VIEW) -> np.ndarray:
    """``a (F, V, C, 3)`` for one light and one RPO (see :func:`shading_set`)."""
    return shading_set(frames, {"l": np.asarray(light, dtype=np.float64)}, {"r": rpo}, view)["l/r"].astype(np.float64)


def shade(v: np.ndarray, a: np.ndarray) -> np.ndarray:
    """``v (F, V, C)``, ``a (F, V, C, 3)`` -> radiance ``(F, V, 3)``."""
    return np.einsum("fvc,fvcr->fvr", np.asarray(v, dtype=np.float64), a)


def unshadowed_visibility(n_vertices: int, order: int, n_frames: int) -> np.ndarray:
    """``(F, V, C)``: SH of the upper-hemisphere indicator (no occlusion) in the local frame."""
    from prt_torch.sh.zonal import hemisphere_zh

    h = zh_to_sh(hemisphere_zh(order), np.array([0.0, 0.0, 1.0]))
    return np.broadcast_to(h, (n_frames, n_vertices, order * order)).copy()

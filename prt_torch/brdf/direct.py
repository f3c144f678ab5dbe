"""Direct light from peak lights (issue 27): ``sum_p E_p f_r(l_p, v) max(n . l_p, 0) V_p`` per vertex.

A peak light (:class:`prt_torch.sg.split.PeakLight`) is a small uniform disc on the sky: a unit direction ``l``
(world, z up, towards the light), an angular radius and an RGB radiance; its power ``E = radiance * solid angle``
is the irradiance it delivers to a surface facing it. Its reflected radiance toward the eye is evaluated at the
disc's centre with the same analytic BRDF the run's RPO was built from (:mod:`prt_torch.brdf.analytic`: Lambert,
Phong, the glTF material's Cook-Torrance), times the disc's visible fraction ``V_p`` in ``[0, 1]`` (its soft
shadow: :func:`prt_torch.bake.peaks.exact_peak_visibility`, :func:`prt_torch.blockers.cones.sphere_peak_visibility`
or the learned blockers). ``max(n . l, 0)`` is the BRDF's own cosine (:meth:`~prt_torch.brdf.analytic.BRDF.
cosine_weighted`) at the disc's centre; the disc's horizon share is also in ``V_p`` (the visibility kernels'
rule), which for a sun-sized disc (a fraction of a degree) changes only vertices within that angle of grazing.

Frames are the vertex frames of the rest of the pipeline (rows ``t, b, n`` in world coordinates; local = ``F @
world``), the BRDF's local ``z`` the normal; a vertex seen from below its horizon reflects nothing (the analytic
BRDFs vanish there; the scoring's silhouette rule). numpy + numba only (the torch-free player uses it).

One implementation, two layouts: :func:`peak_radiance_soa` (vertex-last arrays, the player's) and
:func:`peak_radiance` (vertex-major, compare's and the page check's) run the same compiled pass: the catalogue's BRDF
classes (Lambert, Phong, Blinn-Phong, Cook-Torrance - the glTF material's too -, Ward) through :func:`_brdf_shape`
(the compiled twin of :mod:`prt_torch.brdf.analytic`'s formulas, tested against them), any other
:class:`~prt_torch.brdf.analytic.BRDF` by its own :meth:`~prt_torch.brdf.analytic.BRDF.cosine_weighted` on the
(vertex, peak) pairs that receive light.
"""

from __future__ import annotations

import math
from typing import Any

import numba
import numpy as np

from prt_torch.errors import check
from prt_torch.shapes import check_shape


def view_directions(positions: np.ndarray, eye: np.ndarray) -> np.ndarray:
    """``(..., V, 3)`` float64 unit world directions from each point toward the camera ``eye (3,)``."""
    v = np.asarray(eye, dtype=np.float64) - np.asarray(positions, dtype=np.float64)
    return v / np.maximum(np.linalg.norm(v, axis=-1, keepdims=True), 1e-12)


def peak_radiance(frames: np.ndarray, view: np.ndarray, directions: np.ndarray, powers: np.ndarray,
                  visibility: np.ndarray, brdf: Any, threads: bool = False) -> np.ndarray:
    """Radiance toward the eye reflected from the peak lights, per vertex (module doc): :func:`peak_radiance_soa` on
    vertex-major arrays.

    Args:
        frames: ``(..., V, 3, 3)`` vertex frames, rows ``(t, b, n)`` world.
        view: ``(..., V, 3)`` unit world directions toward the eye (:func:`view_directions`).
        directions: ``(P, 3)`` unit peak directions (world, towards the lights).
        powers: ``(P, 3)`` RGB peak powers ``E`` (radiance x solid angle).
        visibility: ``(..., V, P)`` the discs' visible fractions in ``[0, 1]``.
        brdf: an analytic BRDF (:class:`prt_torch.brdf.analytic.BRDF`; its tint included).
        threads: numba's threads over vertices (``False``: the calling thread only).

    Returns:
        ``(..., V, 3)`` float32 radiance (0 where no peak is given).
    """
    f = np.asarray(frames)
    dims = check_shape(f, "... V 3 3", name="peak shading: frames")
    lead = f.shape[:-2]
    check_shape(view, (*lead, 3), name="peak shading: view directions")
    check_shape(directions, "P 3", name="peak shading: peak directions", dims=dims)
    check_shape(powers, "P 3", name="peak shading: peak powers", dims=dims)
    check_shape(visibility, (*lead, dims["P"]), name="peak shading: peak visibility")
    check(bool(np.isfinite(visibility).all()), "peak shading: peak visibility contains NaN or Inf")
    V, P = dims["V"], dims["P"]
    soa = peak_radiance_soa(f.reshape(-1, V, 9).transpose(0, 2, 1),
                            np.asarray(view).reshape(-1, V, 3).transpose(0, 2, 1), directions, powers,
                            np.asarray(visibility).reshape(-1, V, P), brdf, threads=threads)
    return soa.reshape(*lead, 3)


def _peak_geometry_py(frames: np.ndarray, view: np.ndarray, directions: np.ndarray, visibility: np.ndarray,
                   wi: np.ndarray, wo: np.ndarray, weight: np.ndarray) -> None:  # pragma: no cover (compiled)
    """Per (character, vertex, peak): the local light and view directions (unit, float64) and ``max(n.l, 0) V`` where
    both are above the horizon and the disc is visible (else a weight of 0)."""
    n_b, _, n_v = frames.shape
    n_p = directions.shape[0]
    for bv in numba.prange(n_b * n_v):
        b, v = bv // n_v, bv % n_v
        vx, vy, vz = view[b, 0, v], view[b, 1, v], view[b, 2, v]
        f = frames[b, :, v]
        ox = f[0] * vx + f[1] * vy + f[2] * vz
        oy = f[3] * vx + f[4] * vy + f[5] * vz
        oz = f[6] * vx + f[7] * vy + f[8] * vz
        on = 1.0 / max(math.sqrt(ox * ox + oy * oy + oz * oz), 1e-12)
        for p in range(n_p):
            lx, ly, lz = directions[p, 0], directions[p, 1], directions[p, 2]
            ix = f[0] * lx + f[1] * ly + f[2] * lz
            iy = f[3] * lx + f[4] * ly + f[5] * lz
            iz = f[6] * lx + f[7] * ly + f[8] * lz
            inn = 1.0 / max(math.sqrt(ix * ix + iy * iy + iz * iz), 1e-12)
            k = (b * n_v + v) * n_p + p
            wi[k, 0], wi[k, 1], wi[k, 2] = ix * inn, iy * inn, iz * inn
            wo[k, 0], wo[k, 1], wo[k, 2] = ox * on, oy * on, oz * on
            vis = visibility[b, v, p]
            weight[k] = iz * inn * vis if (iz > 0 and oz > 0 and vis > 0) else 0.0


_peak_geometry = numba.njit(cache=True, nogil=True, parallel=True)(_peak_geometry_py)
_peak_geometry_serial = numba.njit(cache=True, nogil=True)(_peak_geometry_py)


@numba.njit(cache=True, nogil=True, inline="always")
def _brdf_shape(model: int, prm: np.ndarray, ix: float, iy: float, iz: float, ox: float, oy: float,
                oz: float) -> float:  # pragma: no cover (compiled)
    """The analytic BRDFs' scalar shapes (:mod:`prt_torch.brdf.analytic`, the same formulas; both directions unit and
    above the horizon): ``model`` 0 Lambert, 1 Phong ``(e, kd, ks)``, 2 Cook-Torrance ``(alpha, f0, kd, ks)``, 3 Ward
    ``(alpha, kd, ks)``, 4 Blinn-Phong ``(e, kd, ks, norm)``."""
    if model == 0:
        return 1.0 / math.pi
    if model == 1:
        c = max(-ix * ox - iy * oy + iz * oz, 0.0)
        return prm[1] / math.pi + prm[2] * (prm[0] + 2.0) / (2.0 * math.pi) * c ** prm[0]
    hx, hy, hz = ix + ox, iy + oy, iz + oz
    hn = math.sqrt(hx * hx + hy * hy + hz * hz)
    if hn > 0:
        hx, hy, hz = hx / hn, hy / hn, hz / hn
    if model == 2:
        a2 = prm[0] * prm[0]
        ch = max(hz, 0.0)
        d = a2 / (math.pi * (ch * ch * (a2 - 1.0) + 1.0) ** 2)
        g = (2.0 * iz / (iz + math.sqrt(a2 + (1.0 - a2) * iz * iz))) * \
            (2.0 * oz / (oz + math.sqrt(a2 + (1.0 - a2) * oz * oz)))
        f = prm[1] + (1.0 - prm[1]) * (1.0 - min(max(ix * hx + iy * hy + iz * hz, 0.0), 1.0)) ** 5
        return prm[2] / math.pi + prm[3] * d * g * f / (4.0 * iz * oz)
    if model == 3:
        c2 = max(hz, 1e-12) ** 2
        a2 = prm[0] * prm[0]
        return prm[1] / math.pi + prm[2] * math.exp(-((1.0 - c2) / c2) / a2) / (4.0 * math.pi * a2
                                                                                 * math.sqrt(iz * oz))
    return prm[1] / math.pi + prm[2] * prm[3] * max(hz, 0.0) ** prm[0]


def _peak_shading_py(frames: np.ndarray, view: np.ndarray, directions: np.ndarray, powers: np.ndarray,
                     visibility: np.ndarray, model: int, prm: np.ndarray,
                     out: np.ndarray) -> None:  # pragma: no cover (compiled)
    """:func:`peak_radiance_soa`'s whole computation for the analytic BRDFs :func:`_brdf_shape` knows (``powers``
    times the BRDF's tint), one pass per (character, vertex)."""
    n_b, _, n_v = frames.shape
    n_p = directions.shape[0]
    for bv in numba.prange(n_b * n_v):
        b, v = bv // n_v, bv % n_v
        vx, vy, vz = view[b, 0, v], view[b, 1, v], view[b, 2, v]
        f = frames[b, :, v]
        ox = f[0] * vx + f[1] * vy + f[2] * vz
        oy = f[3] * vx + f[4] * vy + f[5] * vz
        oz = f[6] * vx + f[7] * vy + f[8] * vz
        r, g, bl = 0.0, 0.0, 0.0
        if oz > 0:
            on = 1.0 / math.sqrt(ox * ox + oy * oy + oz * oz)
            ox, oy, oz = ox * on, oy * on, oz * on
            for p in range(n_p):
                vis = visibility[b, v, p]
                if vis <= 0:
                    continue
                lx, ly, lz = directions[p, 0], directions[p, 1], directions[p, 2]
                iz = f[6] * lx + f[7] * ly + f[8] * lz
                if iz <= 0:
                    continue
                ix = f[0] * lx + f[1] * ly + f[2] * lz
                iy = f[3] * lx + f[4] * ly + f[5] * lz
                inn = 1.0 / math.sqrt(ix * ix + iy * iy + iz * iz)
                ix, iy, iz = ix * inn, iy * inn, iz * inn
                w = _brdf_shape(model, prm, ix, iy, iz, ox, oy, oz) * iz * vis
                r += w * powers[p, 0]
                g += w * powers[p, 1]
                bl += w * powers[p, 2]
        out[b, v, 0], out[b, v, 1], out[b, v, 2] = r, g, bl


_peak_shading = numba.njit(cache=True, nogil=True, parallel=True)(_peak_shading_py)
_peak_shading_serial = numba.njit(cache=True, nogil=True)(_peak_shading_py)


#: the codes of the analytic BRDF shapes the compiled pass and the exported graphs know (:func:`brdf_code`)
BRDF_CODES = {"lambert": 0, "phong": 1, "cook_torrance": 2, "ward": 3, "blinn_phong": 4}
#: parameters per code (zero-padded to this length)
BRDF_PARAMS = 4


def brdf_code(brdf: Any) -> tuple[int, np.ndarray] | None:
    """``(code, parameters (BRDF_PARAMS,) float64)`` of the analytic shape of ``brdf`` (:data:`BRDF_CODES`: Lambert
    ``()``, Phong ``(e, kd, ks)``, Cook-Torrance ``(alpha, f0, kd, ks)``, Ward ``(alpha, kd, ks)``, Blinn-Phong
    ``(e, kd, ks, norm)``) for a BRDF of exactly one of those classes, else ``None`` (a subclass may change the
    shape: the generic path evaluates it). The compiled pass (:func:`_brdf_shape`) and the exported graphs
    (:mod:`prt_torch.brdf.direct_graph`) take the BRDF as this pair."""
    from prt_torch.brdf.analytic import BlinnPhong, CookTorrance, Lambert, Phong, Ward

    t = type(brdf)
    prm: tuple[float, ...]
    if t is Lambert:
        name, prm = "lambert", ()
    elif t is Phong:
        name, prm = "phong", (brdf.exponent, brdf.kd, brdf.ks)
    elif t is CookTorrance:
        name, prm = "cook_torrance", (brdf.alpha, brdf.f0, brdf.kd, brdf.ks)
    elif t is Ward:
        name, prm = "ward", (brdf.alpha, brdf.kd, brdf.ks)
    elif t is BlinnPhong:
        name, prm = "blinn_phong", (brdf.exponent, brdf.kd, brdf.ks, brdf.norm)
    else:
        return None
    return BRDF_CODES[name], np.asarray(prm + (0.0,) * (BRDF_PARAMS - len(prm)), dtype=np.float64)


def peak_radiance_soa(frames: np.ndarray, view: np.ndarray, directions: np.ndarray, powers: np.ndarray,
                     visibility: np.ndarray, brdf: Any, threads: bool = False) -> np.ndarray:
    """The peak term ``sum_p E_p f_r(l_p, v) max(n . l_p, 0) V_p`` per vertex on vertex-last arrays (module doc).

    Args:
        frames: ``(B, 9, V)`` vertex frames (entry ``3i + j`` is ``F[i, j]``, rows ``t, b, n``, world).
        view: ``(B, 3, V)`` unit directions toward the eye.
        directions: ``(P, 3)`` unit peak directions; powers: ``(P, 3)`` RGB peak powers ``E``.
        visibility: ``(B, V, P)`` the discs' visible fractions.
        brdf: the analytic BRDF the RPO was built from.
        threads: numba's threads over vertices (``False``: the calling thread only).

    Returns:
        ``(B, V, 3)`` float32 radiance (0 where no light arrives or the vertex is seen from below its horizon).
    """
    f = np.ascontiguousarray(frames, dtype=np.float32)
    check_shape(f, "B 9 V", name="peak shading: frames")
    n_b, _, n_v = f.shape
    vw = np.ascontiguousarray(view, dtype=np.float32)
    check_shape(vw, (n_b, 3, n_v), name="peak shading: view directions")
    d = np.ascontiguousarray(directions, dtype=np.float64).reshape(-1, 3)
    n_p = d.shape[0]
    e = np.asarray(powers, dtype=np.float64).reshape(-1, 3)
    check(e.shape == (n_p, 3), f"peak shading: powers must be ({n_p}, 3), got {np.shape(powers)}")
    vis = np.ascontiguousarray(visibility, dtype=np.float32)
    check_shape(vis, (n_b, n_v, n_p), name="peak shading: peak visibility")
    out = np.zeros((n_b, n_v, 3), np.float32)
    if n_p == 0 or n_v == 0:
        return out
    compiled = brdf_code(brdf)
    if compiled is not None:  # one compiled pass, no temporaries
        tinted = np.ascontiguousarray(e * np.asarray(brdf.tint, dtype=np.float64)[None, :])
        (_peak_shading if threads else _peak_shading_serial)(f, vw, d, tinted, vis, compiled[0], compiled[1], out)
        return out
    wi, wo = np.empty((n_b * n_v * n_p, 3)), np.empty((n_b * n_v * n_p, 3))
    weight = np.empty(n_b * n_v * n_p)
    (_peak_geometry if threads else _peak_geometry_serial)(f, vw, d, vis, wi, wo, weight)
    lit = np.flatnonzero(weight)
    if lit.size == 0:
        return out
    # the BRDF's own cosine-weighted shape on the lit pairs only (weight = max(n.l, 0) V there: divided back out)
    wl, ol = wi[lit], wo[lit]
    wl /= np.linalg.norm(wl, axis=1, keepdims=True)  # unit to the BRDF's check (the kernel's float32 products)
    ol /= np.linalg.norm(ol, axis=1, keepdims=True)
    s = brdf.cosine_weighted(wl, ol) * weight[lit] / wl[:, 2]
    rgb = s[:, None] * (np.asarray(brdf.tint, dtype=np.float64)[None, :] * e[lit % n_p])
    flat = out.reshape(-1, 3)
    idx = lit // n_p
    if n_p == 1:
        flat[idx] = rgb
    else:
        for c in range(3):
            flat[:, c] = np.bincount(idx, rgb[:, c], minlength=n_b * n_v)
    return out

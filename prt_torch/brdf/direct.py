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
BRDFs vanish there; the scoring's silhouette rule). numpy only (the torch-free player uses it).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from prt_torch.errors import check
from prt_torch.shapes import check_shape


def view_directions(positions: np.ndarray, eye: np.ndarray) -> np.ndarray:
    """``(..., V, 3)`` float64 unit world directions from each point toward the camera ``eye (3,)``."""
    v = np.asarray(eye, dtype=np.float64) - np.asarray(positions, dtype=np.float64)
    return v / np.maximum(np.linalg.norm(v, axis=-1, keepdims=True), 1e-12)


def peak_radiance(frames: np.ndarray, view: np.ndarray, directions: np.ndarray, powers: np.ndarray,
                  visibility: np.ndarray, brdf: Any) -> np.ndarray:
    """Radiance toward the eye reflected from the peak lights, per vertex (module doc).

    Args:
        frames: ``(..., V, 3, 3)`` vertex frames, rows ``(t, b, n)`` world.
        view: ``(..., V, 3)`` unit world directions toward the eye (:func:`view_directions`).
        directions: ``(P, 3)`` unit peak directions (world, towards the lights).
        powers: ``(P, 3)`` RGB peak powers ``E`` (radiance x solid angle).
        visibility: ``(..., V, P)`` the discs' visible fractions in ``[0, 1]``.
        brdf: an analytic BRDF (:class:`prt_torch.brdf.analytic.BRDF`; its tint included).

    Returns:
        ``(..., V, 3)`` float32 radiance (0 where no peak is given).
    """
    f = np.asarray(frames, dtype=np.float64)
    dims = check_shape(f, "... V 3 3", name="peak shading: frames")
    lead = f.shape[:-2]
    check_shape(view, (*lead, 3), name="peak shading: view directions")
    d = np.asarray(directions, dtype=np.float64)
    check_shape(d, "P 3", name="peak shading: peak directions", dims=dims)
    check_shape(powers, "P 3", name="peak shading: peak powers", dims=dims)
    check_shape(visibility, (*lead, dims["P"]), name="peak shading: peak visibility")
    out = np.zeros((*lead, 3), dtype=np.float64)
    if dims["P"] == 0:
        return out.astype(np.float32)
    check(bool(np.isfinite(visibility).all()), "peak shading: peak visibility contains NaN or Inf")
    wo = np.einsum("...ij,...j->...i", f, np.asarray(view, dtype=np.float64)).reshape(-1, 3)
    wo /= np.maximum(np.linalg.norm(wo, axis=-1, keepdims=True), 1e-12)
    vis = np.asarray(visibility, dtype=np.float64).reshape(-1, dims["P"])
    tint = np.asarray(getattr(brdf, "tint", np.ones(3)), dtype=np.float64)
    flat = out.reshape(-1, 3)
    for p in range(dims["P"]):  # P <= 4 peaks: each one whole-array pass over every vertex
        wi = np.einsum("...ij,j->...i", f, d[p]).reshape(-1, 3)
        wi /= np.maximum(np.linalg.norm(wi, axis=-1, keepdims=True), 1e-12)  # float32 frames: unit to ~1e-6 only
        lit = vis[:, p] > 0
        if not lit.any():
            continue
        fr = brdf.cosine_weighted(wi[lit], wo[lit])  # s(wi, wo) max(wi.z, 0), 0 when wo is below the horizon
        flat[lit] += (fr * vis[lit, p])[:, None] * (tint * np.asarray(powers[p], dtype=np.float64))[None, :]
    return out.astype(np.float32)

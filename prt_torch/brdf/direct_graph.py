"""The peak lights' direct term in torch, for exported graphs (issue 27: the fused graph with peaks,
:class:`prt_torch.export.peaks_graph.FusedPeaksGraph`).

The same computation as :func:`prt_torch.brdf.direct.peak_radiance_soa` (its module doc: ``sum_p E_p f_r(l_p, v)
max(n . l_p, 0) V_p`` per vertex, the BRDF evaluated at each disc's centre, nothing for a vertex seen from below its
horizon) on whole ``(B, P, V)`` tensors, with the BRDF a run-time INPUT rather than a constant: ``brdf (1 +
BRDF_PARAMS,)`` is ``[code, parameters...]`` of :func:`prt_torch.brdf.direct.brdf_code`, every shape of
:data:`~prt_torch.brdf.direct.BRDF_CODES` is evaluated and the code selects one (``Where``), so a graph swaps BRDFs
as the RPO inputs swap RPOs. The formulas are :mod:`prt_torch.brdf.analytic`'s (tested against them and against the
compiled pass).
"""

from __future__ import annotations

import math

import torch

from prt_torch.brdf.direct import BRDF_CODES, BRDF_PARAMS
from prt_torch.shapes import check_shape

#: the floor of the cosines a BRDF divides by (Cook-Torrance, Ward), so that the shapes not selected stay finite
#: where a pair is masked out; a selected pair has both cosines > 0 and its value is unchanged above the floor
COS_FLOOR = 1e-6


def brdf_shapes(brdf: torch.Tensor, wi: torch.Tensor, wo: torch.Tensor) -> torch.Tensor:
    """The BRDF ``f_r(wi, wo)`` of ``brdf = [code, parameters...]`` (module doc) for local unit directions
    ``wi, wo (..., 3)`` above the horizon (``z`` the normal); ``(...)``, the tensors' dtype."""
    ix, iy, iz = wi.unbind(-1)
    ox, oy, oz = wo.unbind(-1)
    code = brdf[0]
    p0, p1, p2, p3 = (brdf[1 + k] for k in range(BRDF_PARAMS))
    izc, ozc = iz.clamp(min=COS_FLOOR), oz.clamp(min=COS_FLOOR)
    lambert = torch.full_like(iz, 1.0 / math.pi)
    c = (-ix * ox - iy * oy + iz * oz).clamp(min=0.0)  # mirror(wi) . wo
    phong = p1 / math.pi + p2 * (p0 + 2.0) / (2.0 * math.pi) * c ** p0
    h = wi + wo
    h = h / torch.linalg.vector_norm(h, dim=-1, keepdim=True).clamp(min=1e-12)
    hz = h[..., 2]
    a2 = p0 * p0
    ch = hz.clamp(min=0.0)
    d = a2 / (math.pi * (ch * ch * (a2 - 1.0) + 1.0) ** 2)
    g = (2.0 * izc / (izc + torch.sqrt(a2 + (1.0 - a2) * izc * izc))) * \
        (2.0 * ozc / (ozc + torch.sqrt(a2 + (1.0 - a2) * ozc * ozc)))
    f = p1 + (1.0 - p1) * (1.0 - (wi * h).sum(-1).clamp(0.0, 1.0)) ** 5
    cook = p2 / math.pi + p3 * d * g * f / (4.0 * izc * ozc)
    c2 = hz.clamp(min=1e-12) ** 2
    ward = p1 / math.pi + p2 * torch.exp(-((1.0 - c2) / c2) / a2) / (4.0 * math.pi * a2 * torch.sqrt(izc * ozc))
    blinn = p1 / math.pi + p2 * p3 * ch ** p0
    out = lambert
    for name, shape in (("phong", phong), ("cook_torrance", cook), ("ward", ward), ("blinn_phong", blinn)):
        out = torch.where(code == BRDF_CODES[name], shape, out)
    return out


def peak_radiance_graph(frames: torch.Tensor, view_dirs: torch.Tensor, directions: torch.Tensor,
                        powers: torch.Tensor, visibility: torch.Tensor, brdf: torch.Tensor) -> torch.Tensor:
    """The peak term on vertex-last tensors (:func:`prt_torch.brdf.direct.peak_radiance_soa`'s layout).

    Args:
        frames: ``(B, 9, V)`` vertex frames (entry ``3i + j`` is ``F[i, j]``, rows ``t, b, n``, world).
        view_dirs: ``(B, 3, V)`` unit directions toward the eye.
        directions: ``(P, 3)`` unit peak directions (world, towards the lights).
        powers: ``(P, 3)`` RGB peak powers ``E``, times the BRDF's tint.
        visibility: ``(B, V, P)`` the discs' visible fractions.
        brdf: ``(1 + BRDF_PARAMS,)`` ``[code, parameters...]`` (module doc).

    Returns:
        ``(B, V, 3)`` radiance.
    """
    dims = check_shape(frames, "B 9 V", name="peak shading: frames")
    check_shape(view_dirs, "B 3 V", name="peak shading: view directions", dims=dims)
    check_shape(directions, "P 3", name="peak shading: directions", dims=dims)
    check_shape(powers, "P 3", name="peak shading: powers", dims=dims)
    check_shape(visibility, "B V P", name="peak shading: peak visibility", dims=dims)
    check_shape(brdf, (1 + BRDF_PARAMS,), name="peak shading: brdf")
    f = frames.reshape(frames.shape[0], 3, 3, frames.shape[2])  # (B, 3 rows, 3, V)
    wo = torch.einsum("bijv,bjv->bvi", f, view_dirs)  # (B, V, 3) local
    wi = torch.einsum("bijv,pj->bpvi", f, directions)  # (B, P, V, 3) local
    front = wo[..., 2] > 0  # (B, V): seen from above the horizon
    lit = wi[..., 2] > 0  # (B, P, V)
    wo = wo / torch.linalg.vector_norm(wo, dim=-1, keepdim=True).clamp(min=1e-12)
    wi = wi / torch.linalg.vector_norm(wi, dim=-1, keepdim=True).clamp(min=1e-12)
    shape = brdf_shapes(brdf, wi, wo[:, None].expand_as(wi))  # (B, P, V)
    w = shape * wi[..., 2] * visibility.permute(0, 2, 1)
    w = torch.where(lit & front[:, None], w, torch.zeros_like(w))
    return torch.einsum("bpv,pc->bvc", w, powers)

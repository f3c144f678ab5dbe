"""Peak-light visibility through capsule blockers (issue 27): the cone-sphere cap overlap of
:mod:`prt_torch.blockers.cones` with each capsule replaced by its sphere nearest the ray.

A capsule is a segment ``a-b`` and a radius ``r`` (:mod:`prt_torch.blockers.capsules`). For a receiver ``p`` and a
peak of direction ``l`` and angular radius ``alpha``, the capsule stands for the sphere of radius ``r`` centred at
``c = a + s (b - a)``, the point of the segment closest to the ray ``p + t l`` (``t >= 0``, ``s`` in ``[0, 1]``:
the closest points of a ray and a segment, both clamped, Ericson 2005 section 5.1.9), and that sphere goes through
the exact cap intersection of :func:`prt_torch.blockers.cones.cap_intersection`. For a delta light this is exact
(the ray hits the capsule iff its distance to the segment is below ``r``, and then it hits that sphere); for a
small disc it is the capsule's shadow up to the penumbra's shape (the sphere's cap instead of the capsule's
outline, the same width). A sphere is a capsule with ``a == b`` (then ``s = 0``, ``c = a``): the results are the
sphere kernel's. A segment parallel to the ray takes ``s = 0``.

The rest is the sphere kernel's rules: the capsules are independent occluders (the product of the visible
fractions), times the share of the disc above the receiver's horizon; a capsule that contains the receiver
(``dist(p, segment) <= r``) is ignored.

Two implementations of the same formulas: :func:`capsule_visibility_soa`, one compiled numba pass per (receiver,
peak) in float64 scalars, vertex-last, with the capsules culled per block of 64 consecutive vertices by their
bounding spheres (centre ``(a + b) / 2``, radius ``r + |b - a| / 2``; the sphere kernel's conservative bound: the
same results as without it); and :func:`capsule_peak_visibility` of torch tensors, whole ``(B, P, V, S)`` arrays of
the closest-point parameters (an exportable graph: no loops; the overlapping triples gathered with ``NonZero`` and
summed with ``ScatterElements`` add), differentiable with finite gradients (square roots floored at
:data:`~prt_torch.blockers.cones.TINY`, divisions guarded). numpy input to :func:`capsule_peak_visibility` goes
to the compiled pass.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, TypeVar

import numpy as np

from prt_torch.blockers.cones import (
    TINY,
    cap_intersection,
    cap_solid_angle,
    capsule_visibility_soa,
    horizon_fraction,
    is_tracing,
)
from prt_torch.errors import check
from prt_torch.sh.basis import check_float_array, is_torch
from prt_torch.shapes import check_shape

if TYPE_CHECKING:
    import torch

Array = TypeVar("Array", "np.ndarray", "torch.Tensor")

def _check_inputs(positions: Array, normals: Array, ends_a: Array, ends_b: Array, radii: Array,
                  directions: Array, angular_radii: Array) -> None:
    """:func:`capsule_peak_visibility`'s argument checks (one-line :class:`PrtError`)."""
    for x, name in ((positions, "receiver positions"), (normals, "receiver normals"), (ends_a, "capsule endpoints"),
                    (ends_b, "capsule endpoints"), (directions, "peak directions")):
        check_float_array(x, name)
    dims = check_shape(positions, "... V 3", name="receiver positions")
    check_shape(normals, tuple(positions.shape), name="receiver normals")
    check_shape(ends_a, (*positions.shape[:-2], "S", 3), name="capsule endpoints a", dims=dims)
    check_shape(ends_b, (*positions.shape[:-2], "S", 3), name="capsule endpoints b", dims=dims)
    check_shape(radii, "S", name="capsule radii", dims=dims)
    check_shape(directions, "P 3", name="peak directions", dims=dims)
    check_shape(angular_radii, "P", name="peak angular radii", dims=dims)
    ar = check_float_array(angular_radii, "peak angular radii")
    check(bool((ar > 0).all() and (ar <= math.pi / 2).all()), "peak angular radii must be in (0, pi/2] radians")
    check(bool((check_float_array(radii, "capsule radii") > 0).all()), "capsule radii must be > 0")


def capsule_peak_visibility(positions: Array, normals: Array, ends_a: Array, ends_b: Array, radii: Array,
                            directions: Array, angular_radii: Array) -> Array:
    """Visible fraction of each peak's disc at each receiver, through capsule blockers (module doc).

    Args:
        positions: ``(..., V, 3)`` receiver points, world (z up); normals: ``(..., V, 3)`` unit normals.
        ends_a, ends_b: ``(..., S, 3)`` posed capsule endpoints, the same leading axes as ``positions``.
        radii: ``(S,)`` capsule radii (> 0).
        directions: ``(P, 3)`` unit peak directions; angular_radii: ``(P,)`` half-angles in ``(0, pi/2]``.

    Returns:
        ``(..., V, P)`` in ``[0, 1]``, the dtype and array type of ``positions`` (numpy: the compiled pass; torch:
        whole arrays, differentiable and exportable).
    """
    if not is_torch(positions):
        _check_inputs(positions, normals, ends_a, ends_b, radii, directions, angular_radii)
        V, S, P = positions.shape[-2], ends_a.shape[-2], directions.shape[0]
        lead = positions.shape[:-2]
        out = capsule_visibility_soa(positions.reshape(-1, V, 3).transpose(0, 2, 1),
                                     normals.reshape(-1, V, 3).transpose(0, 2, 1), ends_a.reshape(-1, S, 3),
                                     ends_b.reshape(-1, S, 3), radii, directions, angular_radii)
        return out.reshape(*lead, V, P).astype(positions.dtype, copy=False)
    import torch as xp

    if not is_tracing(xp):
        _check_inputs(positions, normals, ends_a, ends_b, radii, directions, angular_radii)
    V, S, P = positions.shape[-2], ends_a.shape[-2], directions.shape[0]
    lead = positions.shape[:-2]
    pos, ea, eb = positions.reshape(-1, V, 3), ends_a.reshape(-1, S, 3), ends_b.reshape(-1, S, 3)
    B = pos.shape[0]
    w = eb - ea  # (B, S, 3)
    cc = (w * w).sum(-1)[:, None, None, :]  # (B, 1, 1, S)
    ee = ((w * ea).sum(-1)[:, None, :] - pos @ w.transpose(1, 2))[:, None]  # w.(a - p): (B, 1, V, S)
    bb = (w @ directions.T).transpose(1, 2)[:, :, None, :]  # l.w: (B, P, 1, S)
    dd = (ea @ directions.T).transpose(1, 2)[:, :, None, :] - (pos @ directions.T).transpose(1, 2)[..., None]
    d0 = ((pos * pos).sum(-1)[..., :, None] + (ea * ea).sum(-1)[:, None, :]
          - 2 * pos @ ea.transpose(1, 2))[:, None]  # |a - p|^2: (B, 1, V, S)
    one = xp.ones_like(cc)
    c_safe = xp.where(cc > 0, cc, one)
    sp = xp.where(cc > 0, xp.clamp(-ee / c_safe, 0.0, 1.0), xp.zeros_like(ee))  # the segment point nearest p
    inside = d0 + 2 * sp * ee + sp * sp * cc <= radii * radii
    den = cc - bb * bb  # (B, P, 1, S)
    par = den > 1e-6 * cc
    s = xp.where(par, xp.clamp((dd * bb - ee) / xp.where(par, den, xp.ones_like(den)), 0.0, 1.0),
                 xp.zeros_like(dd * bb - ee))
    s = xp.where(dd + s * bb < 0, sp.expand_as(s), s)  # (B, P, V, S)
    hh = d0 + 2 * s * ee + s * s * cc - radii * radii
    x = dd + s * bb + xp.sin(angular_radii)[:, None, None] * radii
    cos2 = (xp.cos(angular_radii) ** 2)[:, None, None]
    hit = (hh > 0) & (x > 0) & (x * x > cos2 * hh) & ~inside
    flat = hit.reshape(-1).nonzero(as_tuple=True)[0]
    group = flat // S  # flat (B, P, V) index
    k, v, p, b = flat % S, group % V, (group // V) % P, group // (V * P)
    off = (ea.reshape(-1, 3)[b * S + k] + s.reshape(-1)[flat][:, None] * w.reshape(-1, 3)[b * S + k]
           - pos.reshape(-1, 3)[b * V + v])  # (N, 3)
    ln, rs = directions[p], radii[k]
    cx = ln[:, 1] * off[:, 2] - ln[:, 2] * off[:, 1]
    cy = ln[:, 2] * off[:, 0] - ln[:, 0] * off[:, 2]
    cz = ln[:, 0] * off[:, 1] - ln[:, 1] * off[:, 0]
    gamma = xp.atan2(xp.sqrt(xp.clamp(cx * cx + cy * cy + cz * cz, TINY, None)), (ln * off).sum(-1))
    beta = xp.atan2(rs, xp.sqrt(xp.clamp((off * off).sum(-1) - rs * rs, TINY, None)))
    frac = cap_intersection(angular_radii[p], beta, gamma) / cap_solid_angle(angular_radii[p])
    full = frac >= 1
    logs = xp.where(full, xp.zeros_like(frac), xp.log(xp.clamp(1 - frac, TINY, None)))
    n_full = frac.new_zeros(B * P * V).scatter_add(0, group, full.to(frac.dtype))
    vis = xp.exp(frac.new_zeros(B * P * V).scatter_add(0, group, logs)) * (n_full == 0)
    vis = vis.reshape(*lead, P, V).transpose(-1, -2)
    return horizon_fraction(normals, directions, angular_radii) * vis

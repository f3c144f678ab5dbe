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

import numba
import numpy as np

from prt_torch.blockers.cones import TINY, cap_intersection, cap_lens, cap_solid_angle, horizon_fraction, is_tracing
from prt_torch.errors import check
from prt_torch.sh.basis import check_float_array, is_torch
from prt_torch.shapes import check_shape

if TYPE_CHECKING:
    import torch

Array = TypeVar("Array", "np.ndarray", "torch.Tensor")

#: vertices per block of the compiled kernel's capsule culling
_BLOCK = 64


@numba.njit(cache=True, nogil=True, inline="always")
def _ray_segment_s(bb: float, cc: float, dd: float, ee: float) -> float:  # pragma: no cover (compiled)
    """The segment parameter ``s`` in [0, 1] of the closest points of the ray ``p + t l`` (``t >= 0``) and the
    segment ``a + s w``, from ``bb = l.w``, ``cc = w.w``, ``dd = l.(a - p)``, ``ee = w.(a - p)`` (|l| = 1)."""
    if cc <= 0.0:
        return 0.0
    den = cc - bb * bb
    s = min(max((dd * bb - ee) / den, 0.0), 1.0) if den > 1e-12 * cc else 0.0
    if dd + s * bb < 0.0:  # the ray's t would be negative: t = 0, the segment point closest to p
        s = min(max(-ee / cc, 0.0), 1.0)
    return s


def _capsule_visibility_soa_py(positions: np.ndarray, normals: np.ndarray, ends_a: np.ndarray, ends_b: np.ndarray,
                               radii: np.ndarray, directions: np.ndarray, angular_radii: np.ndarray,
                               out: np.ndarray) -> None:  # pragma: no cover (compiled)
    """:func:`capsule_visibility_soa`'s kernel (module doc): per (character, block of :data:`_BLOCK` consecutive
    vertices) and peak, the capsules that can reach the peak's cone from some vertex of the block, then per vertex
    the exact closest point, overlap test and cap intersection against those only.

    Culling (necessary conditions, so the same results as without it): with the block's centre ``m`` and radius
    ``rho``, a capsule whose bounding sphere lies behind every vertex of the block along ``l`` is dropped; else the
    sphere it stands for from a vertex ``p`` (centre ``c`` on the segment) meets the cone only if ``dist(c, line(p,
    l)) <= r + (|c - p| + r) tan a`` (the sphere kernel's bound), and ``dist(segment, line(m, l))`` is at most
    ``rho`` more while ``|c - p| <= max(|a - m|, |b - m|) + rho``: a capsule failing that bound for ``m`` fails
    for every vertex of the block (a relative margin of 1e-4 covers rounding; ``a`` near ``pi / 2`` culls
    nothing)."""
    n_b, _, n_v = positions.shape
    n_s, n_p = ends_a.shape[1], directions.shape[0]
    n_blk = (n_v + _BLOCK - 1) // _BLOCK
    for bb in numba.prange(n_b * n_blk):
        b, v0 = bb // n_blk, (bb % n_blk) * _BLOCK
        v1 = min(v0 + _BLOCK, n_v)
        lo = np.empty(3)
        hi = np.empty(3)
        for k in range(3):
            lo[k], hi[k] = positions[b, k, v0], positions[b, k, v0]
        for v in range(v0, v1):
            for k in range(3):
                lo[k] = min(lo[k], positions[b, k, v])
                hi[k] = max(hi[k], positions[b, k, v])
        mx, my, mz = 0.5 * (lo[0] + hi[0]), 0.5 * (lo[1] + hi[1]), 0.5 * (lo[2] + hi[2])
        rho = 0.5 * math.sqrt((hi[0] - lo[0]) ** 2 + (hi[1] - lo[1]) ** 2 + (hi[2] - lo[2]) ** 2)
        cand = np.empty(n_s, np.int64)
        for p in range(n_p):
            lx, ly, lz = directions[p, 0], directions[p, 1], directions[p, 2]
            alpha = angular_radii[p]
            sin_a, cos_a = math.sin(alpha), math.cos(alpha)
            tan_a = sin_a / cos_a if alpha < 1.5 else math.inf
            cap_a = 4.0 * math.pi * math.sin(alpha / 2) ** 2
            n_c = 0
            for s in range(n_s):  # the capsule against the block's bounding sphere (_capsule_visibility_soa_py)
                r = radii[s]
                dx, dy, dz = ends_a[b, s, 0] - mx, ends_a[b, s, 1] - my, ends_a[b, s, 2] - mz
                wx = ends_b[b, s, 0] - ends_a[b, s, 0]
                wy = ends_b[b, s, 1] - ends_a[b, s, 1]
                wz = ends_b[b, s, 2] - ends_a[b, s, 2]
                half = 0.5 * math.sqrt(wx * wx + wy * wy + wz * wz)
                along = (dx + 0.5 * wx) * lx + (dy + 0.5 * wy) * ly + (dz + 0.5 * wz) * lz
                if along <= -(r + half + rho) * (1 + 1e-4) - 1e-6:  # the bounding sphere behind the block
                    continue
                cc = wx * wx + wy * wy + wz * wz
                bb_ = lx * wx + ly * wy + lz * wz
                dd = lx * dx + ly * dy + lz * dz
                ee = wx * dx + wy * dy + wz * dz
                den = cc - bb_ * bb_
                t = min(max((dd * bb_ - ee) / den, 0.0), 1.0) if den > 1e-12 * cc else 0.0
                qx, qy, qz = dx + t * wx, dy + t * wy, dz + t * wz  # segment point nearest the axis line
                q_along = qx * lx + qy * ly + qz * lz
                perp = math.sqrt(max(qx * qx + qy * qy + qz * qz - q_along * q_along, 0.0))
                far = max(math.sqrt(dx * dx + dy * dy + dz * dz),
                          math.sqrt((dx + wx) ** 2 + (dy + wy) ** 2 + (dz + wz) ** 2))
                reach = r + rho + (far + rho + r) * tan_a
                if perp <= reach * (1 + 1e-4) + 1e-6:
                    cand[n_c] = s
                    n_c += 1
            for v in range(v0, v1):
                px, py, pz = positions[b, 0, v], positions[b, 1, v], positions[b, 2, v]
                nx, ny, nz = normals[b, 0, v], normals[b, 1, v], normals[b, 2, v]
                cos_g = nx * lx + ny * ly + nz * lz
                if cos_g >= sin_a:  # the share of the disc above the horizon (cones.horizon_fraction)
                    h = 1.0
                elif cos_g <= -sin_a:
                    h = 0.0
                else:
                    cx, cy, cz = ny * lz - nz * ly, nz * lx - nx * lz, nx * ly - ny * lx
                    g = math.atan2(math.sqrt(max(cx * cx + cy * cy + cz * cz, TINY)), cos_g)
                    h = cap_lens(alpha, math.pi / 2, g) / cap_a
                if h <= 0.0:
                    out[b, v, p] = 0.0
                    continue
                vis = h
                for j in range(n_c):
                    s = cand[j]
                    r = radii[s]
                    dx, dy, dz = ends_a[b, s, 0] - px, ends_a[b, s, 1] - py, ends_a[b, s, 2] - pz
                    wx = ends_b[b, s, 0] - ends_a[b, s, 0]
                    wy = ends_b[b, s, 1] - ends_a[b, s, 1]
                    wz = ends_b[b, s, 2] - ends_a[b, s, 2]
                    cc = wx * wx + wy * wy + wz * wz
                    ee = wx * dx + wy * dy + wz * dz
                    sp = min(max(-ee / cc, 0.0), 1.0) if cc > 0.0 else 0.0  # the segment point closest to p
                    qx, qy, qz = dx + sp * wx, dy + sp * wy, dz + sp * wz
                    if qx * qx + qy * qy + qz * qz <= r * r:  # the receiver inside the capsule: ignored
                        continue
                    t = _ray_segment_s(lx * wx + ly * wy + lz * wz, cc, lx * dx + ly * dy + lz * dz, ee)
                    ox, oy, oz = dx + t * wx, dy + t * wy, dz + t * wz
                    hh = ox * ox + oy * oy + oz * oz - r * r
                    x = ox * lx + oy * ly + oz * lz + r * sin_a
                    if not (hh > 0 and x > 0 and x * x > cos_a * cos_a * hh):  # cones' overlap test
                        continue
                    cx, cy, cz = ly * oz - lz * oy, lz * ox - lx * oz, lx * oy - ly * ox
                    g = math.atan2(math.sqrt(max(cx * cx + cy * cy + cz * cz, TINY)), lx * ox + ly * oy + lz * oz)
                    beta = math.atan2(r, math.sqrt(max(hh, TINY)))
                    frac = cap_lens(alpha, beta, g) / cap_a
                    if frac >= 1.0:
                        vis = 0.0
                        break
                    vis *= 1.0 - frac
                out[b, v, p] = vis


#: the kernel compiled twice: threads over vertex blocks (numba's), and one thread
_capsule_visibility_soa = numba.njit(cache=True, nogil=True, parallel=True)(_capsule_visibility_soa_py)
_capsule_visibility_soa_serial = numba.njit(cache=True, nogil=True)(_capsule_visibility_soa_py)


def capsule_visibility_soa(positions: np.ndarray, normals: np.ndarray, ends_a: np.ndarray, ends_b: np.ndarray,
                           radii: np.ndarray, directions: np.ndarray, angular_radii: np.ndarray,
                           threads: bool = False) -> np.ndarray:
    """Visible fraction of each peak's disc through capsule blockers, one compiled pass, vertex-last (module doc).

    Args:
        positions, normals: ``(B, 3, V)`` world receivers and their unit normals (vertex-last, the player's layout).
        ends_a, ends_b: ``(B, S, 3)`` posed capsule endpoints (:func:`prt_torch.blockers.capsules.pose_capsules`);
            radii: ``(S,)`` (> 0).
        directions: ``(P, 3)`` unit peak directions; angular_radii: ``(P,)`` half-angles in ``(0, pi/2]``.
        threads: numba's threads over vertex blocks (``False``: the calling thread only).

    Returns:
        ``(B, V, P)`` in ``[0, 1]``: float64 for float64 positions, else float32.
    """
    dtype = np.float64 if np.asarray(positions).dtype == np.float64 else np.float32
    pos = np.ascontiguousarray(positions, dtype=dtype)
    check_shape(pos, "B 3 V", name="peak visibility: positions")
    nrm = np.ascontiguousarray(normals, dtype=dtype)
    check_shape(nrm, tuple(pos.shape), name="peak visibility: normals")
    ea = np.ascontiguousarray(ends_a, dtype=dtype)
    check_shape(ea, (pos.shape[0], "S", 3), name="peak visibility: capsule endpoints a")
    eb = np.ascontiguousarray(ends_b, dtype=dtype)
    check_shape(eb, tuple(ea.shape), name="peak visibility: capsule endpoints b")
    rad = np.ascontiguousarray(radii, dtype=dtype)
    check_shape(rad, (ea.shape[1],), name="peak visibility: capsule radii")
    check(bool((rad > 0).all()), "capsule radii must be > 0")
    d = np.ascontiguousarray(directions, dtype=np.float64).reshape(-1, 3)
    ar = np.ascontiguousarray(angular_radii, dtype=np.float64).reshape(-1)
    check(ar.shape == (d.shape[0],) and bool(((ar > 0) & (ar <= math.pi / 2)).all()),
          "peak angular radii must be (P,) in (0, pi/2] radians")
    out = np.empty((pos.shape[0], pos.shape[2], d.shape[0]), dtype)
    if out.size:
        (_capsule_visibility_soa if threads else _capsule_visibility_soa_serial)(pos, nrm, ea, eb, rad, d, ar, out)
    return out


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

"""Peak-light visibility through sphere blockers: analytic cone-sphere occlusion (issue 27, ``peaks_spheres``).

What Unreal's capsule direct shadows do, with spheres and the exact spherical-cap overlap instead of a
smoothstep. A peak light is a uniform disc on the sky: the cone (spherical cap) of half-angle ``a`` (its angular
radius) about its unit direction ``l``. Seen from a receiver ``p``, a sphere ``(c, R)`` with ``d = |c - p| > R`` is
the cap of half-angle ``b = asin(R / d)`` about ``(c - p) / d``; the fraction of the light it hides is the solid
angle of the intersection of the two caps over the light's ``2 pi (1 - cos a)``.

**Cap intersection** (:func:`cap_intersection`; caps of half-angles ``a, b`` in ``[0, pi/2]``, axes ``gamma``
apart): ``0`` when ``gamma >= a + b``, the smaller cap when ``gamma <= |a - b|``, else the lens. The lens is
bounded by two circle arcs meeting at the corners ``X, X'``; with the spherical triangle ``(C_a, C_b, X)`` of sides
``a, b, gamma`` (angles ``phi_a`` at ``C_a``, ``phi_b`` at ``C_b``, spherical excess ``E``), the lens is the two
cap sectors minus the kite ``C_a X C_b X'``::

    Omega = 2 phi_a (1 - cos a) + 2 phi_b (1 - cos b) - 2 E

which is Gauss-Bonnet's ``2 (pi - psi) - 2 phi_a cos a - 2 phi_b cos b`` (``psi`` the triangle's angle at ``X``;
Tovchigrechko & Vakser 2001, Mazonka 2012 "Solid angle of conical surfaces, polyhedral cones, and intersecting
spherical caps", arXiv:1205.1396) with ``E = phi_a + phi_b + psi - pi`` taken out, written so that no term cancels
for a sun-sized ``a`` (0.005 rad: the textbook form loses 7 digits there): ``1 - cos x = 2 sin^2(x / 2)``, the
angles by the half-angle formulas ``tan(phi_a / 2) = sqrt(sin(s - a) sin(s - gamma) / (sin s sin(s - b)))``
(``s = (a + b + gamma) / 2``) and the excess by L'Huilier's theorem ``tan(E / 4) = sqrt(tan(s/2) tan((s-a)/2)
tan((s-b)/2) tan((s-gamma)/2))``. With ``gamma`` clamped to ``[|a - b|, a + b]`` the same expression is ``0`` and
the smaller cap at the two ends, so it holds everywhere (identical caps, ``gamma = 0, a = b``, is set apart).

**Visibility** (:func:`sphere_peak_visibility`): per receiver and peak,
``H * prod_s (1 - occlusion_s)`` -- the spheres are combined as *independent occluders* (the product of the
per-sphere visible fractions; exact when at most one sphere overlaps the disc, too dark where overlapping spheres
hide the same part of it). ``H`` is the share of the disc above the receiver's horizon (the cap of half-angle
``pi / 2`` about the normal: :func:`cap_intersection` again), so that samples below the horizon count as not
visible, the rule of the Embree oracle :func:`prt_torch.bake.peaks.exact_peak_visibility`. A sphere that contains
the receiver (``d <= R``) is ignored, as in SHEXP (:mod:`prt_torch.shexp.visibility`).

numpy or torch, the same code (torch is never imported here: numpy inputs never touch it); the pairs that overlap
are found with one test without trigonometry (``gamma < a + b`` iff ``(c - p) . l > cos a sqrt(d^2 - R^2) - R sin
a``) and only they go through the formula; the product over spheres is a sum of ``log(1 - occlusion)`` per receiver
and peak, full occlusions counted apart. numpy inputs: one compiled numba pass does it all per (receiver, peak) in
float64 scalars, blockers culled per block of consecutive vertices (:func:`sphere_visibility_soa`, also the player's
path on its vertex-last arrays). The pass is the capsules' (:func:`capsule_visibility_soa`, the capsule rules of
:mod:`prt_torch.blockers.capsule_cones`): a sphere is a capsule with ``a == b``, whose closest point to any ray is
its centre, so one compiled kernel serves both; torch inputs: whole ``(..., P, V, S)`` arrays, the overlapping
triples gathered again exactly and summed with ``scatter_add`` (an exportable graph, ``NonZero`` +
``ScatterElements``). Measured on the built-in character (11.7k vertices, 48 spheres, one frame, 1 peak): numba
~1.0-1.6 ms (the array path it replaced: ~3.5 ms).
"""

from __future__ import annotations

import math
from types import ModuleType
from typing import TYPE_CHECKING, Any, TypeVar

import numba
import numpy as np

from prt_torch.errors import check
from prt_torch.sh.basis import check_float_array, is_torch
from prt_torch.shapes import check_shape

if TYPE_CHECKING:
    import torch

Array = TypeVar("Array", "np.ndarray", "torch.Tensor")


def _xp(x: Any) -> ModuleType:
    if is_torch(x):
        import torch

        return torch
    return np


def cap_solid_angle(half_angle: Array) -> Array:
    """Solid angle ``2 pi (1 - cos x) = 4 pi sin^2(x / 2)`` of caps of half-angles ``x`` (radians, any shape)."""
    xp = _xp(half_angle)
    return 4 * math.pi * xp.sin(half_angle / 2) ** 2


#: the floor of every square root's argument: ``sqrt`` of an exact 0 has an infinite derivative, which times the 0
#: of a clamp or of the branch ``where`` does not take is NaN in the learned blockers' gradients
#: (:mod:`prt_torch.models.peak_blockers`); ``sqrt(1e-30) = 1e-15`` moves no result by more than that
TINY = 1e-30


def _sqrt(xp: ModuleType, x: Array) -> Array:
    """``sqrt(max(x, TINY))``: finite values and finite derivatives everywhere (:data:`TINY`)."""
    return xp.sqrt(xp.clip(x, TINY, None))


def cap_intersection(a: Array, b: Array, gamma: Array) -> Array:
    """Solid angle of the intersection of two spherical caps (module doc for the formula).

    Args:
        a, b: the caps' half-angles, radians in ``[0, pi/2]`` (broadcast together).
        gamma: the angle between their axes, radians in ``[0, pi]``.

    Returns:
        The intersection's solid angle (sr), the broadcast shape, the inputs' type and dtype.
    """
    xp = _xp(gamma)
    lo = xp.abs(a - b)
    g = xp.clip(xp.clip(gamma, lo, None), None, a + b)  # beyond a + b: no lens; below |a - b|: containment
    s = (a + b + g) / 2
    sa, sb, sg = xp.clip(s - a, 0.0, None), xp.clip(s - b, 0.0, None), xp.clip(s - g, 0.0, None)
    sin_s = xp.sin(s)
    phi_a = 2 * xp.arctan2(_sqrt(xp, xp.sin(sa) * xp.sin(sg)), _sqrt(xp, sin_s * xp.sin(sb)))
    phi_b = 2 * xp.arctan2(_sqrt(xp, xp.sin(sb) * xp.sin(sg)), _sqrt(xp, sin_s * xp.sin(sa)))
    excess = 4 * xp.arctan(_sqrt(xp, xp.tan(s / 2) * xp.tan(sa / 2) * xp.tan(sb / 2) * xp.tan(sg / 2)))
    lens = 4 * phi_a * xp.sin(a / 2) ** 2 + 4 * phi_b * xp.sin(b / 2) ** 2 - 2 * excess
    inside = gamma <= lo  # the smaller cap, also for identical caps (a = b, gamma = 0, where the lens is 0 / 0)
    lens = xp.where(gamma >= a + b, xp.zeros_like(lens), lens)  # apart: exactly 0 (not the TINY floor's 1e-15)
    return xp.clip(xp.where(inside, cap_solid_angle(xp.minimum(a, b)), lens), 0.0, None)


def _cross_norm(u: Array, w: Array) -> Array:
    """``|u x w|`` over the last axis (explicit components: numpy and torch alike)."""
    cx = u[..., 1] * w[..., 2] - u[..., 2] * w[..., 1]
    cy = u[..., 2] * w[..., 0] - u[..., 0] * w[..., 2]
    cz = u[..., 0] * w[..., 1] - u[..., 1] * w[..., 0]
    return _sqrt(_xp(cx), cx * cx + cy * cy + cz * cz)


def horizon_fraction(normals: Array, directions: Array, angular_radii: Array) -> Array:
    """``(..., V, P)``: the share of each peak's disc above each receiver's horizon (``n . w > 0``); the formula runs
    only where the horizon cuts the disc (``|n . l| < sin a``), elsewhere the share is 1 or 0.

    Args:
        normals: ``(..., V, 3)`` unit receiver normals.
        directions: ``(P, 3)`` unit peak directions.
        angular_radii: ``(P,)`` the discs' half-angles (radians, in ``(0, pi/2]``).
    """
    xp = _xp(normals)
    cos_g = normals @ directions.T  # (..., V, P)
    out = (cos_g > 0) * xp.ones_like(cos_g)
    cut = _nonzero(xp.abs(cos_g) < xp.sin(angular_radii))
    a = angular_radii[cut[-1]]
    gamma = xp.arctan2(_cross_norm(normals[cut[:-1]], directions[cut[-1]]), cos_g[cut])
    out[cut] = cap_intersection(a, 0 * a + math.pi / 2, gamma) / cap_solid_angle(a)
    return out


def _nonzero(mask: Any) -> tuple[Any, ...]:
    return mask.nonzero(as_tuple=True) if is_torch(mask) else np.nonzero(mask)


def _sum_at(index: Any, weights: Any, size: Any) -> Any:
    """``out[i] = sum of weights[index == i]``, ``(size,)`` (torch: the array path's sums; ONNX ScatterElements)."""
    return weights.new_zeros(size).scatter_add(0, index, weights)


@numba.njit(cache=True, nogil=True, inline="always")
def cap_lens(a: float, b: float, gamma: float) -> float:  # pragma: no cover (compiled)
    """Scalar :func:`cap_intersection` (the same half-angle and L'Huilier formulas and clamps, float64)."""
    lo = abs(a - b)
    if gamma >= a + b:
        return 0.0
    if gamma <= lo:
        m = min(a, b)
        return 4.0 * math.pi * math.sin(m / 2) ** 2
    s = (a + b + gamma) / 2
    sa, sb, sg = max(s - a, 0.0), max(s - b, 0.0), max(s - gamma, 0.0)
    sin_s = math.sin(s)
    phi_a = 2.0 * math.atan2(math.sqrt(max(math.sin(sa) * math.sin(sg), TINY)),
                             math.sqrt(max(sin_s * math.sin(sb), TINY)))
    phi_b = 2.0 * math.atan2(math.sqrt(max(math.sin(sb) * math.sin(sg), TINY)),
                             math.sqrt(max(sin_s * math.sin(sa), TINY)))
    t = math.tan(s / 2) * math.tan(sa / 2) * math.tan(sb / 2) * math.tan(sg / 2)
    excess = 4.0 * math.atan(math.sqrt(max(t, TINY)))
    lens = 4.0 * phi_a * math.sin(a / 2) ** 2 + 4.0 * phi_b * math.sin(b / 2) ** 2 - 2.0 * excess
    return max(lens, 0.0)


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
    """:func:`capsule_visibility_soa`'s kernel (:mod:`prt_torch.blockers.capsule_cones`'s doc; spheres: ``a == b``):
    per (character, block of :data:`_BLOCK` consecutive vertices) and peak, the capsules that can reach the peak's
    cone from some vertex of the block, then per vertex the exact closest point, overlap test and cap intersection
    against those only.

    Culling (necessary conditions, so the same results as without it): with the block's centre ``m`` and radius
    ``rho``, a capsule whose bounding sphere lies behind every vertex of the block along ``l`` is dropped; else the
    sphere it stands for from a vertex ``p`` (centre ``c`` on the segment) meets the cone only if ``dist(c, line(p,
    l)) <= r + (|c - p| + r) tan a`` (a sphere's bound), and ``dist(segment, line(m, l))`` is at most
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
        cw = np.empty((n_s, 3))  # the candidates' segment vectors b - a and their squared lengths
        ccs = np.empty(n_s)
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
                    cw[n_c, 0], cw[n_c, 1], cw[n_c, 2], ccs[n_c] = wx, wy, wz, cc
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
                    cc = ccs[j]
                    if cc > 0.0:
                        wx, wy, wz = cw[j, 0], cw[j, 1], cw[j, 2]
                        ee = wx * dx + wy * dy + wz * dz
                        sp = min(max(-ee / cc, 0.0), 1.0)  # the segment point closest to p
                        qx, qy, qz = dx + sp * wx, dy + sp * wy, dz + sp * wz
                        if qx * qx + qy * qy + qz * qz <= r * r:  # the receiver inside the capsule: ignored
                            continue
                        t = _ray_segment_s(lx * wx + ly * wy + lz * wz, cc, lx * dx + ly * dy + lz * dz, ee)
                        ox, oy, oz = dx + t * wx, dy + t * wy, dz + t * wz
                    else:  # a sphere (a == b): its centre; a receiver inside it fails the overlap test (hh <= 0)
                        ox, oy, oz = dx, dy, dz
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
    return _blocker_pass(positions, normals, ends_a, ends_b, radii, directions, angular_radii, threads, "capsule")


def _blocker_pass(positions: np.ndarray, normals: np.ndarray, ends_a: np.ndarray, ends_b: np.ndarray,
                  radii: np.ndarray, directions: np.ndarray, angular_radii: np.ndarray, threads: bool,
                  what: str) -> np.ndarray:
    """The checks and the compiled pass of :func:`capsule_visibility_soa` and :func:`sphere_visibility_soa`
    (``what``: ``"capsule"`` or ``"sphere"``, for the errors)."""
    dtype = np.float64 if np.asarray(positions).dtype == np.float64 else np.float32
    pos = np.ascontiguousarray(positions, dtype=dtype)
    check_shape(pos, "B 3 V", name="peak visibility: positions")
    nrm = np.ascontiguousarray(normals, dtype=dtype)
    check_shape(nrm, tuple(pos.shape), name="peak visibility: normals")
    ends = "endpoints a" if what == "capsule" else "centres"
    ea = np.ascontiguousarray(ends_a, dtype=dtype)
    check_shape(ea, (pos.shape[0], "S", 3), name=f"peak visibility: {what} {ends}")
    eb = ea if ends_b is ends_a else np.ascontiguousarray(ends_b, dtype=dtype)
    check_shape(eb, tuple(ea.shape), name=f"peak visibility: {what} endpoints b")
    rad = np.ascontiguousarray(radii, dtype=dtype)
    check_shape(rad, (ea.shape[1],), name=f"peak visibility: {what} radii")
    check(bool((rad > 0).all()), f"{what} radii must be > 0")
    d = np.ascontiguousarray(directions, dtype=np.float64).reshape(-1, 3)
    ar = np.ascontiguousarray(angular_radii, dtype=np.float64).reshape(-1)
    check(ar.shape == (d.shape[0],) and bool(((ar > 0) & (ar <= math.pi / 2)).all()),
          "peak angular radii must be (P,) in (0, pi/2] radians")
    out = np.empty((pos.shape[0], pos.shape[2], d.shape[0]), dtype)
    if out.size:  # a sphere is a capsule with a == b (the segment's closest point is its centre): one kernel
        (_capsule_visibility_soa if threads else _capsule_visibility_soa_serial)(pos, nrm, ea, eb, rad, d, ar, out)
    return out


def sphere_visibility_soa(positions: np.ndarray, normals: np.ndarray, centers: np.ndarray, radii: np.ndarray,
                          directions: np.ndarray, angular_radii: np.ndarray, threads: bool = False) -> np.ndarray:
    """:func:`sphere_peak_visibility` of numpy arrays in one compiled pass, vertex-last (the player's layout).

    The same cone-sphere occlusion (overlap test, cap intersection, independent occluders, the disc's horizon share)
    fused per vertex in float64 arithmetic, parallel over blocks of consecutive vertices (numba threads), each block
    testing only the spheres that can reach the peak's cone from it (a conservative bound: the same results as
    without it), without the gathers and temporary arrays of the general function.

    Args:
        positions, normals: ``(B, 3, V)`` float32 world receivers and their unit normals (vertex-last: a
            :class:`~prt_torch.player.posing.PoseBatch`'s rows).
        centers: ``(B, S, 3)`` posed sphere centres; radii: ``(S,)``.
        directions: ``(P, 3)`` unit peak directions; angular_radii: ``(P,)`` half-angles in ``(0, pi/2]``.
        threads: numba's threads over vertices (``False``: the calling thread only).

    Returns:
        ``(B, V, P)`` visible fractions in ``[0, 1]``: float64 for float64 positions, else float32.
    """
    return _blocker_pass(positions, normals, centers, centers, radii, directions, angular_radii, threads, "sphere")


def is_tracing(xp: ModuleType) -> bool:
    """Whether torch is tracing (an ONNX export): shapes are then traced values, not checked."""
    return xp is not np and bool(xp.jit.is_tracing() or xp.onnx.is_in_onnx_export())


def _check_inputs(positions: Array, normals: Array, centers: Array, radii: Array, directions: Array,
                  angular_radii: Array) -> None:
    """:func:`sphere_peak_visibility`'s argument checks (one-line :class:`PrtError`)."""
    for x, name in ((positions, "receiver positions"), (normals, "receiver normals"), (centers, "sphere centres"),
                    (directions, "peak directions")):
        check_float_array(x, name)
    dims = check_shape(positions, "... V 3", name="receiver positions")
    check_shape(normals, tuple(positions.shape), name="receiver normals")
    check_shape(centers, (*positions.shape[:-2], "S", 3), name="sphere centres", dims=dims)
    check_shape(radii, "S", name="sphere radii", dims=dims)
    check_shape(directions, "P 3", name="peak directions", dims=dims)
    check_shape(angular_radii, "P", name="peak angular radii", dims=dims)
    ar = check_float_array(angular_radii, "peak angular radii")
    check(bool((ar > 0).all() and (ar <= math.pi / 2).all()), "peak angular radii must be in (0, pi/2] radians")
    check(bool((check_float_array(radii, "sphere radii") > 0).all()), "sphere radii must be > 0")


def sphere_peak_visibility(positions: Array, normals: Array, centers: Array, radii: Array, directions: Array,
                           angular_radii: Array) -> Array:
    """Visible fraction of each peak's disc at each receiver, through sphere blockers (module doc).

    Args:
        positions: ``(..., V, 3)`` receiver points, world (z up).
        normals: ``(..., V, 3)`` their unit normals (the horizon).
        centers: ``(..., S, 3)`` posed sphere centres (:func:`prt_torch.blockers.pose_spheres`), the same leading
            axes as ``positions``.
        radii: ``(S,)`` sphere radii (> 0).
        directions: ``(P, 3)`` unit peak directions (towards the light).
        angular_radii: ``(P,)`` the peaks' angular radii (half-angles, radians, in ``(0, pi/2]``).

    Returns:
        ``(..., V, P)`` in ``[0, 1]``, the dtype and array type of ``positions`` (numpy or torch).
    """
    xp = _xp(positions)
    if not is_tracing(xp):  # checked on every call; an ONNX export traces the computation only (dynamic B, V, P)
        _check_inputs(positions, normals, centers, radii, directions, angular_radii)
    V, S, P = positions.shape[-2], centers.shape[-2], directions.shape[0]
    lead = positions.shape[:-2]
    pos3, cen3 = positions.reshape(-1, V, 3), centers.reshape(-1, S, 3)
    B = pos3.shape[0]
    # the test gamma < a + b on every (receiver, sphere, peak), in (..., P, V, S) order, without trigonometry:
    # (c - p) . l + R sin a > cos a |c - p| cos b; a sphere containing the receiver gets |c - p| cos b = inf
    if xp is np:  # one compiled pass: the horizon, the test and the formula per (receiver, peak, sphere)
        out = sphere_visibility_soa(pos3.transpose(0, 2, 1), normals.reshape(-1, V, 3).transpose(0, 2, 1), cen3, radii,
                                    directions, angular_radii)
        return out.reshape(*lead, V, P).astype(positions.dtype, copy=False)
    # torch: whole arrays (an exportable graph)
    d2 = ((positions * positions).sum(-1)[..., :, None] + (centers * centers).sum(-1)[..., None, :]
          - 2 * positions @ xp.swapaxes(centers, -1, -2))  # (..., V, S)
    r2 = radii * radii
    cos_b_d = xp.where(d2 > r2, xp.sqrt(xp.clip(d2 - r2, 0.0, None)), xp.full_like(d2, math.inf))
    lp = xp.swapaxes(positions @ directions.T, -1, -2)  # (..., P, V)
    lc = xp.swapaxes(centers @ directions.T, -1, -2) + xp.sin(angular_radii)[:, None] * radii  # (..., P, S)
    hit = (lc[..., :, None, :] - lp[..., :, :, None]) > (xp.cos(angular_radii)[:, None, None]
                                                        * cos_b_d[..., None, :, :])
    flat = _nonzero(hit.reshape(-1))[0]
    # the overlapping triples' geometry, gathered exactly
    group = flat // S  # flat (..., P, V) index
    s, v, p, b = flat % S, group % V, (group // V) % P, group // (V * P)
    off = cen3.reshape(-1, 3)[b * S + s] - pos3.reshape(-1, 3)[b * V + v]  # (N, 3)
    ln, rs = directions[p], radii[s]
    gamma = xp.arctan2(_cross_norm(ln, off), (ln * off).sum(-1))
    beta = xp.arctan2(rs, _sqrt(xp, (off * off).sum(-1) - rs * rs))
    frac = cap_intersection(angular_radii[p], beta, gamma) / cap_solid_angle(angular_radii[p])
    # product over spheres: the sum of log(1 - occlusion) per (receiver, peak), a full occlusion counted apart
    full = frac >= 1
    logs = xp.where(full, xp.zeros_like(frac), xp.log(xp.clip(1 - frac, TINY, None)))
    n_full = _sum_at(group, full * xp.ones_like(frac), B * P * V)
    vis = xp.exp(_sum_at(group, logs, B * P * V)) * (n_full == 0)
    vis = xp.swapaxes(vis.reshape(*lead, P, V), -1, -2)
    return horizon_fraction(normals, directions, angular_radii) * vis

"""Which cones to trace: the aperture of an SG lobe (seed 004 eq. 5-6), 7 sub-cones per BRDF lobe by circle
packing (Fig. 4), a single cone for a very specular lobe, and one cone per detected light peak (Figs. 6, 8).

Sub-cone packing (Fig. 4): the lobe ``G(v) = exp(lambda (v.p - 1))`` is covered out to its *extent* ``R``, the
angle where ``G`` falls to ``extent_level`` (default 0.1), at most 90 degrees (a BRDF lobe never needs the
lower hemisphere around its own axis). Seven equal circles pack a circle of radius ``R`` optimally with radius
``beta = R / 3``: one at the axis and six at polar angle ``2 beta``, 60 degrees apart (the ring's azimuth is
fixed by a stable tangent frame of the axis). Each cone's weight is the lobe's integral over its cell (the
central cap ``theta < beta``, and six 60-degree sectors beyond it), in closed form:
``w_0 = (1 - exp(-lambda (1 - cos beta))) / (1 - exp(-2 lambda))``, ``w_k = (1 - w_0) / 6``; they sum to 1.
A lobe with ``lambda >= specular_sharpness`` gets one cone of the eq. 6 aperture and weight 1.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from prt_torch.errors import PrtError, check
from prt_torch.shapes import check_shape

LOG_HALF = math.log(0.5)
#: lobes at least this sharp get a single cone (eq. 6 aperture ~4.8 degrees)
SPECULAR_SHARPNESS = 200.0
#: the lobe value at the packed extent
EXTENT_LEVEL = 0.1
#: narrowest cone traced (radians); a peak smaller than this is traced with this aperture
MIN_HALF_ANGLE = math.radians(0.5)


def _check_sharpness(sharpness: torch.Tensor) -> None:
    if not bool(torch.isfinite(sharpness).all()):
        raise PrtError("SG sharpness (lambda) contains NaN or Inf")
    if bool((sharpness <= 0).any()):
        raise PrtError(f"SG sharpness (lambda) must be > 0, got min {float(sharpness.min()):g}")


def cone_aperture(sharpness: torch.Tensor) -> torch.Tensor:
    """Eq. 6: the half-angle ``alpha = acos(log(0.5) / lambda + 1)`` where the SG falls to 0.5 (``pi`` for
    lobes too wide to fall to 0.5 on the sphere, ``lambda < log(2) / 2``)."""
    sharpness = torch.as_tensor(sharpness)
    _check_sharpness(sharpness)
    return torch.acos((LOG_HALF / sharpness + 1.0).clamp(-1.0, 1.0))


def cone_sharpness(half_angle: torch.Tensor) -> torch.Tensor:
    """The inverse of eq. 6: the SG sharpness whose half-value angle is ``half_angle`` (radians, in (0, pi])."""
    half_angle = torch.as_tensor(half_angle)
    if not bool(((half_angle > 0) & (half_angle <= math.pi)).all()):
        raise PrtError("cone half-angles must lie in (0, pi]")
    return LOG_HALF / (torch.cos(half_angle) - 1.0)


def tangent_frame(axis: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Two unit tangents ``(..., 3)`` completing ``axis (..., 3)`` to a right-handed orthonormal frame
    (Duff et al. 2017, branchless)."""
    x, y, z = axis.unbind(-1)
    s = torch.where(z >= 0, torch.ones_like(z), -torch.ones_like(z))
    a = -1.0 / (s + z)
    b = x * y * a
    t1 = torch.stack([1.0 + s * x * x * a, s * b, -s * x], dim=-1)
    t2 = torch.stack([b, s + y * y * a, -y], dim=-1)
    return t1, t2


def lobe_extent(sharpness: torch.Tensor, level: float = EXTENT_LEVEL) -> torch.Tensor:
    """The angle where the unit SG falls to ``level``, capped at 90 degrees."""
    c = (1.0 + math.log(level) / sharpness).clamp(0.0, 1.0)
    return torch.acos(c)


@dataclass
class ConeSet:
    """Cones per vertex: ``dirs (..., N, 3)`` unit world axes, ``half_angle (..., N)`` radians, ``weights
    (..., N)`` (each lobe's packing weights, summing to 1 within the lobe) and ``group (N,)`` long: the BRDF
    lobe index of each cone, or ``-1 - p`` for the cone of light peak ``p``."""

    dirs: torch.Tensor
    half_angle: torch.Tensor
    weights: torch.Tensor
    group: torch.Tensor

    @staticmethod
    def cat(sets: list[ConeSet]) -> ConeSet:
        return ConeSet(torch.cat([s.dirs for s in sets], dim=-2), torch.cat([s.half_angle for s in sets], dim=-1),
                       torch.cat([s.weights for s in sets], dim=-1), torch.cat([s.group for s in sets]))


def cones_per_lobe(sharpness: float, specular_sharpness: float = SPECULAR_SHARPNESS) -> int:
    """7 sub-cones, or 1 for a lobe at least ``specular_sharpness`` sharp."""
    check(math.isfinite(sharpness) and sharpness > 0, f"SG sharpness (lambda) must be > 0, got {sharpness}")
    return 1 if sharpness >= specular_sharpness else 7


def pack_lobe_cones(axis: torch.Tensor, sharpness: torch.Tensor, n_cones: int = 7,
                    extent_level: float = EXTENT_LEVEL) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """The cones of SG lobes ``axis (..., 3)`` (unit), ``sharpness (...,)``: ``n_cones = 7`` by circle packing
    (module docstring) or ``1`` (the eq. 6 cone along the axis). Returns ``dirs (..., n, 3)``, ``half_angle
    (..., n)``, ``weights (..., n)``."""
    check(n_cones in (1, 7), f"n_cones must be 1 or 7, got {n_cones}")
    sharpness = torch.as_tensor(sharpness, dtype=axis.dtype, device=axis.device)
    _check_sharpness(sharpness)
    check(axis.shape[-1] == 3 and axis.shape[:-1] == sharpness.shape,
          f"lobe axes (..., 3) and sharpness (...) disagree: {tuple(axis.shape)} vs {tuple(sharpness.shape)}")
    if n_cones == 1:
        a = cone_aperture(sharpness).clamp(min=MIN_HALF_ANGLE)
        return axis[..., None, :], a[..., None], torch.ones_like(a)[..., None]
    beta = lobe_extent(sharpness, extent_level) / 3.0
    t1, t2 = tangent_frame(axis)
    phi = torch.arange(6, dtype=axis.dtype, device=axis.device) * (math.pi / 3.0)  # (6,)
    th = (2.0 * beta)[..., None]  # (..., 1)
    ring = (torch.cos(th)[..., None] * axis[..., None, :]
            + torch.sin(th)[..., None] * (torch.cos(phi)[:, None] * t1[..., None, :]
                                          + torch.sin(phi)[:, None] * t2[..., None, :]))
    dirs = torch.cat([axis[..., None, :], ring], dim=-2)
    half = beta[..., None].expand(*beta.shape, 7).clamp(min=MIN_HALF_ANGLE)
    w0 = -torch.expm1(-sharpness * (1 - torch.cos(beta))) / -torch.expm1(-2.0 * sharpness)
    weights = torch.cat([w0[..., None], ((1 - w0) / 6.0)[..., None].expand(*w0.shape, 6)], dim=-1)
    return dirs, half.contiguous(), weights


def peak_cones(direction: torch.Tensor, solid_angle: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """One cone per light peak: ``direction (K, 3)`` unit world, ``solid_angle (K,)`` steradians -> ``dirs
    (K, 3)``, ``half_angle (K,)`` of the cap with that solid angle, ``acos(1 - Omega / 2 pi)`` (at least
    :data:`MIN_HALF_ANGLE`)."""
    check_shape(direction, "K 3", name="peak directions")
    if not (bool(torch.isfinite(direction).all()) and bool(torch.isfinite(solid_angle).all())):
        raise PrtError("peak directions or solid angles contain NaN or Inf")
    check(bool((solid_angle > 0).all()), "peak solid angles must be > 0")
    d = direction / direction.norm(dim=-1, keepdim=True).clamp(min=1e-12)
    half = torch.acos((1.0 - solid_angle / (2 * math.pi)).clamp(-1.0, 1.0)).clamp(min=MIN_HALF_ANGLE)
    return d, half

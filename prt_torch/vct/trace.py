"""Cone tracing through an :class:`~prt_torch.vct.pyramid.OpacityPyramid` (Crassin et al. 2011), vectorised.

Every cone starts at its vertex moved ``start_offset`` voxels along the vertex normal and marches front to
back: at distance ``d`` (voxels) its footprint diameter is ``D = max(2 d tan(half_angle), 1)``, sampled at
level of detail ``log2(D)`` of the pyramid (quadrilinear, one ``grid_sample`` call per step for all cones),
composited ``a += (1 - a) alpha`` with the step-corrected opacity ``alpha = 1 - (1 - o)^(step / D)``, and
advanced by ``step_fraction * D``. The footprint is also limited by the sample's height above the vertex's
tangent plane (the level is at most ``floor(log2((height - 0.5) / 1.5))``: a trilinear sample reads voxels up
to 1.5 voxels away) so a cone never reads the surface it leaves (no self-shadowing
of a flat or convex surface; the cost is a finer, noisier footprint for cones near the horizon). A cone stops
when it leaves the grid or is opaque (``a >= opaque``); visibility is ``1 - a``. The loop is over march steps;
the active cones are compacted as they finish.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from prt_torch.errors import PrtError, check
from prt_torch.vct.grid import VoxelGrid
from prt_torch.vct.pyramid import OpacityPyramid


@dataclass(frozen=True)
class TraceSettings:
    """``start_offset``: voxels along the normal before the first sample; ``start_distance``: voxels along the
    cone of the first sample; ``step_fraction``: step / footprint diameter; ``opaque``: stop opacity;
    ``max_steps``: cap on march steps; ``tangent_clip``: limit the footprint by the height above the tangent
    plane; ``composite``: ``"alpha"`` (front-to-back ``a += (1 - a) alpha``) or ``"max"`` (the largest footprint
    opacity met); ``density``: opacity per footprint length of an occupied level voxel (``alpha = 1 - (1 - o)^(
    density step / D)``; 0.5 halves the over-occlusion of correlated partial coverage, see DESIGN notes);
    ``min_step``: smallest step in voxels (narrow cones)."""

    start_offset: float = 2.0
    start_distance: float = 0.5
    step_fraction: float = 0.5
    opaque: float = 0.995
    max_steps: int = 512
    tangent_clip: bool = True
    composite: str = "alpha"
    density: float = 0.5
    min_step: float = 1.0
    clip_reach: float = 1.5
    clip_floor: bool = True

    def __post_init__(self) -> None:
        check(self.start_offset >= 0 and self.start_distance >= 0, "cone start offsets must be >= 0")
        check(0 < self.step_fraction <= 2, f"step_fraction must be in (0, 2], got {self.step_fraction}")
        check(0 < self.opaque <= 1, f"opaque must be in (0, 1], got {self.opaque}")
        check(self.max_steps >= 1, f"max_steps must be >= 1, got {self.max_steps}")


def _exit_distance(u: torch.Tensor, w: torch.Tensor, size: float) -> torch.Tensor:
    """Distance along ``w`` from ``u`` (inside or outside) to where the ray leaves the box ``[0, size]^3``."""
    safe = torch.where(w.abs() < 1e-9, torch.full_like(w, 1e-9), w)
    t0 = (0.0 - u) / safe
    t1 = (size - u) / safe
    return torch.maximum(t0, t1).min(dim=-1).values.clamp(min=0.0)


def trace_cones(pyramid: OpacityPyramid, grid: VoxelGrid, origins: torch.Tensor, dirs: torch.Tensor,
                half_angle: torch.Tensor, normals: torch.Tensor, settings: TraceSettings | None = None) -> torch.Tensor:
    """Visibility ``(P,)`` in [0, 1] of ``P`` cones: apex ``origins (P, 3)`` world (the vertex), unit axes
    ``dirs (P, 3)``, ``half_angle (P,)`` radians, the vertices' unit ``normals (P, 3)``."""
    s = settings or TraceSettings()
    p = origins.shape[0]
    check(origins.shape == (p, 3) and dirs.shape == (p, 3) and normals.shape == (p, 3)
          and half_angle.shape == (p,), "trace_cones: origins, dirs, normals (P, 3) and half_angle (P,) disagree")
    for name, t in (("cone origins", origins), ("cone directions", dirs), ("normals", normals),
                    ("cone half-angles", half_angle)):
        if not bool(torch.isfinite(t).all()):
            raise PrtError(f"trace_cones: {name} contain NaN or Inf")
    dt = torch.float32
    u0 = grid.to_voxel(origins.to(dt)) + s.start_offset * normals.to(dt)
    w = dirs.to(dt)
    tan2 = 2.0 * torch.tan(half_angle.to(dt).clamp(max=math.radians(89.0)))
    wn = (w * normals.to(dt)).sum(-1)
    d = torch.full((p,), float(s.start_distance), dtype=dt, device=origins.device)
    d_end = _exit_distance(u0, w, float(grid.resolution))
    acc = torch.zeros(p, dtype=dt, device=origins.device)
    idx = torch.arange(p, device=origins.device)
    # the compacted state of the active cones; finished cones are frozen and dropped once a quarter has finished
    live = torch.ones(p, dtype=torch.bool, device=origins.device)
    cu, cw, ct, cwn, cd, cend, ca, cl = u0, w, tan2, wn, d, d_end, acc, live
    for _ in range(s.max_steps):
        if idx.numel() == 0:
            break
        diam = (cd * ct).clamp(min=1.0)
        lod = torch.log2(diam)
        if s.tangent_clip:  # the coarsest level whose voxels (reach 1.5 voxels) stay above the surface layer
            height = s.start_offset + cd * cwn
            cap = torch.log2(((height - 0.5) / s.clip_reach).clamp(min=1.0))
            lod = torch.minimum(lod, cap.floor() if s.clip_floor else cap)
            diam = torch.pow(2.0, lod)
        pos = cu + cd[:, None] * cw
        occ = pyramid.sample(pos, lod)
        step = (s.step_fraction * diam).clamp(min=s.min_step)
        if s.composite == "max":
            new = torch.maximum(ca, occ)
        else:
            alpha = 1.0 - torch.pow((1.0 - occ).clamp(min=0.0), s.density * step / diam)
            new = ca + (1.0 - ca) * alpha
        ca = torch.where(cl, new, ca)
        cd = cd + step
        cl = cl & (cd < cend) & (ca < s.opaque)
        n_live = int(cl.sum())
        if n_live == 0 or n_live < 0.75 * idx.numel():
            acc[idx] = ca
            keep = cl.nonzero().squeeze(1)
            idx, cu, cw, ct, cwn, cd, cend, ca, cl = (x[keep] for x in (idx, cu, cw, ct, cwn, cd, cend, ca, cl))
    acc[idx] = ca
    return (1.0 - acc).clamp(0.0, 1.0)

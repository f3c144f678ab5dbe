"""Per-vertex SH visibility of a dynamic height field (seed 003 eq. 4-5, after [SN08]) in the local vertex frame.

Per frame (torch, vectorised over vertices; no Python loop over vertices or texels):

1. Horizon angles ``h_i`` per vertex and wedge from the max pyramid
   (:func:`prt_torch.heightfield.horizon.horizon_angles`, optionally searched at a ``stride`` and interpolated).
2. The tangent-plane elevation of each wedge centre, ``alpha_i = atan(grad H . u_i)`` with
   ``grad H = -n_xy / n_z`` from the vertex normal (the frame's third row): a direction ``s`` of world
   azimuth ``phi`` is above the local horizon (``s . n >= 0``) exactly when its elevation is ``>= alpha(phi)``.
3. Eq. 4 with eq. 1's convention: ``V(s) = 0`` where ``s`` is below the terrain horizon *and* above the
   tangent plane. Per wedge that is the elevation band ``[alpha_i, max(h_i, alpha_i))`` (both bounds held
   constant over the wedge: the approximation of [SN08]); its SH is a difference of two rows (nearest
   elevation of a fine table, :data:`TABLE_BINS`) of the rotated wedge table
   (:class:`~prt_torch.heightfield.wedges.WedgeTable`), and eq. 5 sums them:
   ``occ_world = sum_i T_i(max(h_i, alpha_i)) - T_i(alpha_i)`` (two ``embedding_bag`` gather-and-sums).
4. Into the vertex frame (rows ``t, b, n``): ``occ_local = D(F) occ_world``, applied as three SH
   z-rotations and two fixed matrices (:class:`~prt_torch.heightfield.zrotation.ZRotator`), then
   ``"one"`` (seed 003 eq. 1, the bake's default): ``v = sqrt(4 pi) e_0 - occ_local``;
   ``"zero"``: ``v = hemisphere(n) - occ_local`` (upper-hemisphere indicator about local ``+z``).

A flat plane has ``h_i = alpha_i = 0``, so ``occ = 0`` and ``v`` is the unoccluded visibility exactly.
The output is the bake's local-frame SH (docs/DESIGN.md), so RPOs shade it unchanged.
"""

from __future__ import annotations

import math

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from prt_torch.bake.trace import check_below_horizon
from prt_torch.errors import check
from prt_torch.heightfield.horizon import REACH, horizon_angles
from prt_torch.heightfield.surface import check_extent, check_heights
from prt_torch.heightfield.wedges import TABLE_BINS, WedgeTable
from prt_torch.heightfield.zrotation import ZRotator
from prt_torch.sh.zonal import hemisphere_zh, zh_to_sh

#: default SH order and number of wedges
ORDER, WEDGES = 4, 16


class HeightFieldVisibility(nn.Module):
    """Height-field SH visibility generator (see the module docstring).

    Args:
        order: SH order ``n`` of the output (``C = n*n``).
        n_wedges: azimuthal wedges.
        stride: horizon search stride (1 = every vertex).
        reach: horizon schedule ``rho`` (:data:`prt_torch.heightfield.horizon.REACH`).
        below_horizon: ``"one"`` (default, seed 003 eq. 1) or ``"zero"`` (docs/DESIGN.md).
        bins: elevation samples of the wedge table.
    """

    def __init__(self, order: int = ORDER, n_wedges: int = WEDGES, stride: int = 1, reach: int = REACH,
                 below_horizon: str = "one", bins: int = TABLE_BINS) -> None:
        super().__init__()
        self.table = WedgeTable.make(order, n_wedges, bins)
        for name, val in (("stride", stride), ("reach", reach)):
            check(isinstance(val, int | np.integer) and not isinstance(val, bool) and val >= 1,
                  f"horizon {name} must be an integer >= 1, got {val!r}")
        self.order, self.n_wedges, self.stride, self.reach = int(order), int(n_wedges), int(stride), int(reach)
        self.below_horizon = check_below_horizon(below_horizon)
        c = self.order ** 2
        k = self.table.elevations.shape[0]
        self.register_buffer("rows", torch.as_tensor(self.table.rotated.reshape(-1, c), dtype=torch.float32))
        az = self.table.azimuths
        self.register_buffer("dirs", torch.as_tensor(np.stack([np.cos(az), np.sin(az)], 1), dtype=torch.float32))
        if self.below_horizon == "one":
            base = np.zeros(c)
            base[0] = math.sqrt(4 * math.pi)
        else:
            base = zh_to_sh(hemisphere_zh(self.order), np.array([0.0, 0.0, 1.0]))
        self.register_buffer("base", torch.as_tensor(base, dtype=torch.float32))
        self.bins = k
        self.register_buffer("offsets", torch.arange(self.n_wedges) * k)
        self.rotator = ZRotator(self.order)

    @property
    def n_bytes(self) -> int:
        """Run-time data: the rotated wedge table (float32) plus the tiny per-wedge constants."""
        return int(sum(b.numel() * b.element_size() for b in self.buffers()))

    def _rows(self, ang: torch.Tensor) -> torch.Tensor:
        """Nearest rows of the flat table ``(n * K, C)`` for angles ``(V, n)`` (wedge ``i`` in column ``i``)."""
        t = (ang.clamp(-math.pi / 2, math.pi / 2) + math.pi / 2) * ((self.bins - 1) / math.pi)
        return torch.round(t).long() + self.offsets

    def occlusion_world(self, horizons: torch.Tensor, normals: torch.Tensor) -> torch.Tensor:
        """``(V, C)`` world-frame SH of the occluded directions above the tangent plane (eq. 5):
        ``sum_i T_i(max(h_i, alpha_i)) - T_i(alpha_i)`` (nearest table rows, two ``embedding_bag`` sums; an
        unoccluded wedge reads the same row twice and contributes exactly 0).

        Args:
            horizons: ``(V, n)`` horizon elevations (radians) per wedge.
            normals: ``(V, 3)`` unit vertex normals (``n_z > 0``).
        """
        grad = -normals[:, :2] / normals[:, 2:3].clamp_min(1e-6)  # (V, 2) dH/dx, dH/dy
        alpha = torch.atan(grad @ self.dirs.T)  # (V, n) tangent-plane elevation at each wedge centre
        top = torch.maximum(horizons.to(alpha.dtype), alpha)
        return (F.embedding_bag(self._rows(top), self.rows, mode="sum")
                - F.embedding_bag(self._rows(alpha), self.rows, mode="sum"))

    def to_local(self, occ_world: torch.Tensor, frames: torch.Tensor) -> torch.Tensor:
        """``(V, C)`` visibility in the vertex frames ``(V, 3, 3)`` (rows t, b, n) from the world occlusion
        ``(V, C)``, rotated with z-rotations (:class:`~prt_torch.heightfield.zrotation.ZRotator`)."""
        occ = self.rotator(occ_world.T.contiguous(), frames)  # (C, V)
        return (self.base[:, None] - occ).T

    def forward(self, heights: torch.Tensor | np.ndarray, frames: torch.Tensor | np.ndarray,
                extent: float = 1.0) -> torch.Tensor:
        """``(V, C)`` float32 local-frame SH visibility of every vertex ``v = iy * N + ix``.

        Args:
            heights: ``(N, N)`` heights (world units).
            frames: ``(N*N, 3, 3)`` vertex frames, rows ``(t, b, n)``
                (:func:`prt_torch.heightfield.surface.grid_frames`).
            extent: side of the square (world units).
        """
        check_heights(heights)
        check_extent(extent)
        h = torch.as_tensor(heights, dtype=torch.float32)
        n = h.shape[0]
        fr = torch.as_tensor(frames, dtype=torch.float32)
        check(tuple(fr.shape) == (n * n, 3, 3), f"frames must have shape ({n * n}, 3, 3) for a {n} x {n} grid, "
              f"got {tuple(fr.shape)}")
        check(bool(torch.isfinite(fr).all()), "vertex frames contain NaN or Inf")
        ang = horizon_angles(h, self.n_wedges, extent, self.stride, self.reach).reshape(n * n, -1)
        return self.to_local(self.occlusion_world(ang, fr[:, 2]), fr)

"""The opacity mip pyramid, packed into one 3D atlas so ONE ``grid_sample`` call reads any level per sample.

Level ``l`` (voxel size ``2^l h``) is the ``avg_pool3d`` of level ``l - 1`` (odd sizes are zero-padded first:
outside the grid is empty). The atlas stacks the levels along x, each followed by one empty voxel slab, inside
a ``(X, R, R)`` tensor whose unused parts are empty too, so trilinear sampling at a level never bleeds into
its neighbour as long as the sample lies within half a voxel of the level's box (:meth:`OpacityPyramid.sample`
zeroes samples outside).
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
import torch.nn.functional as F

from prt_torch.shapes import check_shape


@dataclass
class OpacityPyramid:
    """``atlas (X, R, R)`` float32, ``sizes[l]`` voxels per side of level ``l``, ``offsets[l]`` its first x slab."""

    atlas: torch.Tensor
    sizes: list[int]
    offsets: list[int]

    @property
    def levels(self) -> int:
        return len(self.sizes)

    def sample(self, u: torch.Tensor, lod: torch.Tensor) -> torch.Tensor:
        """Quadrilinear opacity at continuous level-0 voxel coordinates ``u (P, 3)`` and level of detail
        ``lod (P,)`` (clamped to ``[0, levels - 1]``): trilinear in the two nearest levels, linear between them."""
        lod = lod.clamp(0.0, self.levels - 1.0)
        l0 = lod.floor().long().clamp_(max=self.levels - 1)
        l1 = (l0 + 1).clamp_(max=self.levels - 1)
        t = lod - l0.to(lod.dtype)
        sizes = torch.as_tensor(self.sizes, device=u.device, dtype=u.dtype)
        offs = torch.as_tensor(self.offsets, device=u.device, dtype=u.dtype)
        ll = torch.cat([l0, l1])
        scale = torch.pow(2.0, ll.to(u.dtype))[:, None]
        ul = torch.cat([u, u]) / scale  # level coordinates
        n = sizes[ll][:, None]
        inside = ((ul >= -0.5) & (ul <= n + 0.5)).all(dim=-1)
        xa, ya, za = self.atlas.shape
        gx = 2.0 * (ul[:, 0] + offs[ll]) / xa - 1.0
        gy = 2.0 * ul[:, 1] / ya - 1.0
        gz = 2.0 * ul[:, 2] / za - 1.0
        grid = torch.stack([gz, gy, gx], dim=-1).view(1, 1, 1, -1, 3).to(self.atlas.dtype)
        val = F.grid_sample(self.atlas[None, None], grid, mode="bilinear", padding_mode="zeros",
                            align_corners=False).view(-1).to(u.dtype)
        val = val * inside
        p = u.shape[0]
        return (1 - t) * val[:p] + t * val[p:]


def build_pyramid(occupancy: torch.Tensor, min_size: int = 2) -> OpacityPyramid:
    """The pyramid of a cubic ``(R, R, R)`` opacity grid, down to levels of ``min_size`` voxels per side."""
    check_shape(occupancy, "R R R", name="occupancy (a cubic grid)")
    levels = [occupancy.to(torch.float32)]
    while levels[-1].shape[0] > min_size:
        x = levels[-1]
        if x.shape[0] % 2:
            x = F.pad(x, (0, 1, 0, 1, 0, 1))
        levels.append(F.avg_pool3d(x[None, None], kernel_size=2)[0, 0])
    r = occupancy.shape[0]
    sizes = [int(v.shape[0]) for v in levels]
    offsets, x = [], 0
    for s in sizes:
        offsets.append(x)
        x += s + 1
    atlas = torch.zeros((x, r, r), dtype=torch.float32, device=occupancy.device)
    for off, v in zip(offsets, levels, strict=True):  # a loop over the <= 9 levels
        s = v.shape[0]
        atlas[off:off + s, :s, :s] = v
    return OpacityPyramid(atlas, sizes, offsets)

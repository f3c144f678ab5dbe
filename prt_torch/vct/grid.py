"""The dense voxel grid of one frame: a cube ``[origin, origin + resolution * voxel]^3`` in world units."""

from __future__ import annotations

from dataclasses import dataclass

import torch

from prt_torch.errors import PrtError, check
from prt_torch.shapes import check_shape

#: allowed grid resolutions (voxels per side); 64-256 is the useful range
MIN_RESOLUTION, MAX_RESOLUTION = 16, 512
#: a mesh must span at least this many voxels along its longest side
MIN_MESH_VOXELS = 8


@dataclass(frozen=True)
class VoxelGrid:
    """``origin (3,)`` world corner (a tensor on the grid's device), ``voxel`` edge length (world units) and
    ``resolution`` voxels per side. Voxel ``(i, j, k)`` (x, y, z) covers ``origin + voxel * [i, i+1) x ...``."""

    origin: torch.Tensor
    voxel: float
    resolution: int

    @property
    def size(self) -> float:
        return self.voxel * self.resolution

    def to_voxel(self, points: torch.Tensor) -> torch.Tensor:
        """Continuous voxel coordinates ``(..., 3)`` of world ``points (..., 3)`` (voxel ``i`` spans ``[i, i+1)``)."""
        return (points - self.origin.to(points.dtype)) / self.voxel


def check_resolution(resolution: int) -> int:
    check(isinstance(resolution, int) and MIN_RESOLUTION <= resolution <= MAX_RESOLUTION,
          f"voxel grid resolution must be an integer in [{MIN_RESOLUTION}, {MAX_RESOLUTION}], got {resolution!r}")
    return int(resolution)


def check_positions(vertices: torch.Tensor, what: str = "vertex positions") -> None:
    check_shape(vertices, "V 3", name=what)
    check(vertices.shape[0] > 0, f"{what} must have shape (V, 3) with V > 0, got {tuple(vertices.shape)}")
    if not bool(torch.isfinite(vertices).all()):
        raise PrtError(f"{what} contain NaN or Inf")


def fit_grid(vertices: torch.Tensor, resolution: int, margin_voxels: float = 4.0,
             bounds: tuple[tuple[float, float, float], tuple[float, float, float]] | None = None) -> VoxelGrid:
    """A cubic grid around ``vertices (V, 3)``: the bounding box's longest side plus ``margin_voxels`` on each
    side, centred on the box; or the fixed cube ``bounds = (lo, hi)`` (the mesh must lie inside it).

    Raises :class:`PrtError` for NaN positions, a bad resolution, a mesh outside ``bounds`` or a grid too coarse
    for the mesh (fewer than ``MIN_MESH_VOXELS`` voxels along the mesh's longest side)."""
    resolution = check_resolution(resolution)
    check_positions(vertices)
    lo = vertices.min(dim=0).values
    hi = vertices.max(dim=0).values
    extent = float((hi - lo).max())
    check(extent > 0, "the mesh has zero extent: nothing to voxelise")
    if bounds is not None:
        blo = torch.as_tensor(bounds[0], dtype=vertices.dtype, device=vertices.device)
        bhi = torch.as_tensor(bounds[1], dtype=vertices.dtype, device=vertices.device)
        size = float((bhi - blo).max())
        check(size > 0 and bool((bhi > blo).all()), f"voxel grid bounds must have lo < hi, got {bounds}")
        if not (bool((lo >= blo).all()) and bool((hi <= bhi).all())):
            raise PrtError(f"voxel grid too small for the mesh: mesh box {lo.tolist()}..{hi.tolist()} is not inside "
                           f"the grid box {blo.tolist()}..{bhi.tolist()}")
        voxel = size / resolution
        origin = blo
    else:
        check(resolution > 2 * margin_voxels + MIN_MESH_VOXELS,
              f"voxel grid too small for the mesh: {resolution} voxels cannot hold a {margin_voxels:g}-voxel margin")
        voxel = extent / (resolution - 2 * margin_voxels)
        origin = 0.5 * (lo + hi) - 0.5 * voxel * resolution
    if extent / voxel < MIN_MESH_VOXELS:
        raise PrtError(f"voxel grid too small for the mesh: it spans {extent / voxel:.1f} voxels "
                       f"(need >= {MIN_MESH_VOXELS}); raise the resolution")
    return VoxelGrid(origin.detach().clone(), float(voxel), resolution)

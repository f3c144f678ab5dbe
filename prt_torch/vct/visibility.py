"""Per-frame cone-traced visibility of a posed mesh: voxelise, build the pyramid, trace every vertex's cones."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import torch

from prt_torch.errors import check
from prt_torch.shapes import check_shape
from prt_torch.vct.cones import ConeSet
from prt_torch.vct.grid import VoxelGrid, check_positions, check_resolution, fit_grid
from prt_torch.vct.pyramid import OpacityPyramid, build_pyramid
from prt_torch.vct.trace import TraceSettings, trace_cones
from prt_torch.vct.voxelize import is_closed_mesh, voxelize


@dataclass
class VoxelFrame:
    """One frame's voxelisation: the ``grid``, ``occupancy (R, R, R)`` and its ``pyramid``."""

    grid: VoxelGrid
    occupancy: torch.Tensor
    pyramid: OpacityPyramid


@dataclass
class ConeTracer:
    """Cone-traced visibility for a mesh with fixed ``faces (T, 3)``.

    Args:
        faces: triangle indices (numpy or torch; moved to ``device``).
        resolution: voxels per side (64-256 typical).
        solid: fill the interior by ray parity; ``None``: when the mesh is closed (every edge shared twice).
        settings: :class:`TraceSettings`.
        device: where the grids and cones live (``None``: the device of the positions given per frame).
    """

    faces: np.ndarray | torch.Tensor
    resolution: int = 128
    solid: bool | None = None
    settings: TraceSettings = field(default_factory=TraceSettings)
    margin_voxels: float = 4.0

    def __post_init__(self) -> None:
        check_resolution(self.resolution)
        f = torch.as_tensor(np.asarray(self.faces.cpu() if isinstance(self.faces, torch.Tensor) else self.faces),
                            dtype=torch.long)
        check_shape(f, "T 3", name="faces")
        check(len(f) > 0, f"faces must be (T, 3) with T > 0, got {tuple(f.shape)}")
        if self.solid is None:
            self.solid = is_closed_mesh(f.numpy())
        self._faces = {torch.device("cpu"): f}

    def faces_on(self, device: torch.device) -> torch.Tensor:
        if device not in self._faces:
            self._faces[device] = self._faces[torch.device("cpu")].to(device)
        return self._faces[device]

    def voxelize(self, positions: torch.Tensor) -> VoxelFrame:
        """Voxelise the posed mesh ``positions (V, 3)`` (world) and build its pyramid."""
        check_positions(positions)
        grid = fit_grid(positions, self.resolution, self.margin_voxels)
        occ = voxelize(positions, self.faces_on(positions.device), grid, solid=bool(self.solid))
        return VoxelFrame(grid, occ, build_pyramid(occ))

    def trace(self, frame: VoxelFrame, positions: torch.Tensor, normals: torch.Tensor, cones: ConeSet) -> torch.Tensor:
        """Visibility ``(V, N)`` of the cones ``cones.dirs (V, N, 3)``, ``cones.half_angle (V, N)`` (or ``(N, 3)``,
        ``(N,)`` shared by every vertex) from ``positions (V, 3)`` with unit ``normals (V, 3)``."""
        v = positions.shape[0]
        dirs, half = cones.dirs, cones.half_angle
        if dirs.ndim == 2:
            dirs = dirs[None].expand(v, -1, -1)
            half = half[None].expand(v, -1)
        n = dirs.shape[1]
        dims = check_shape(dirs, (v, "N", 3), name="cone directions")
        check_shape(half, (v, "N"), name="cone half-angles", dims=dims)
        org = positions[:, None, :].expand(v, n, 3).reshape(-1, 3)
        nrm = normals[:, None, :].expand(v, n, 3).reshape(-1, 3)
        vis = trace_cones(frame.pyramid, frame.grid, org, dirs.reshape(-1, 3), half.reshape(-1), nrm, self.settings)
        return vis.view(v, n)

    def __call__(self, positions: torch.Tensor, normals: torch.Tensor, cones: ConeSet) -> torch.Tensor:
        """Voxelise + trace in one call: visibility ``(V, N)``."""
        return self.trace(self.voxelize(positions), positions, normals, cones)


def lobe_visibility(vis: torch.Tensor, cones: ConeSet, n_groups: int) -> torch.Tensor:
    """``(V, n_groups)``: each BRDF lobe's packing-weighted cone visibility (``sum_c w_c V_c`` over its cones)."""
    g = cones.group
    w = cones.weights if cones.weights.ndim == 2 else cones.weights[None].expand_as(vis)
    out = torch.zeros(vis.shape[0], n_groups, dtype=vis.dtype, device=vis.device)
    sel = g >= 0
    return out.index_add_(1, g[sel], (w * vis)[:, sel])

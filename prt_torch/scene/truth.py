"""Whole-scene ground truth: Embree over the ground and every posed character of one frame.

One merged triangle mesh (ground + all posed characters) is one :class:`prt_torch.bake.embree.RayScene`;
every receiver set (the ground's vertices in the ground frame, each character's vertices in its vertex frames)
is traced against it with the bake's own per-frame code, :func:`prt_torch.bake.trace.trace_frame` (``scene=``),
so the rays, their per-vertex rotation, the SH projection and the below-horizon convention are exactly the
bake's. Characters use their dataset's ``below_horizon``; the ground uses ``"one"`` (seed 003 eq. 1: the
constant 1 below its horizon, which is what sphere-blocker SHEXP produces there; the diffuse RPO's cosine makes
the two conventions shade identically).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from prt_torch.bake.embree import RayScene
from prt_torch.bake.trace import RaySet, trace_frame
from prt_torch.errors import check

#: the ground's below-horizon convention (module docstring)
GROUND_BELOW_HORIZON = "one"
#: rays per ground vertex of the truth (at least; the ground is cheap next to the characters, and its truth is the
#: yardstick of a smooth soft shadow, so it gets more rays than a bake's 64-128 to keep its noise below the error)
GROUND_TRUTH_RAYS = 1024


def merged_mesh(meshes: list[tuple[np.ndarray, np.ndarray]]) -> tuple[np.ndarray, np.ndarray]:
    """Concatenate ``[(vertices (V_k, 3), faces (T_k, 3)), ...]`` into one ``(vertices, faces)``."""
    check(len(meshes) > 0, "merged mesh: no meshes")
    verts, faces, base = [], [], 0
    for v, f in meshes:
        v = np.asarray(v, dtype=np.float32)
        verts.append(v)
        faces.append(np.asarray(f, dtype=np.int64) + base)
        base += len(v)
    return np.concatenate(verts), np.concatenate(faces)


@dataclass
class SceneTracer:
    """Traces receivers against a merged scene with fixed ray sets (one per receiver size and convention).

    Args:
        order: SH order; n_rays: hemisphere rays per vertex; offset: ray-origin offset along the normal
            (world units; the bake's ``ray_offset_world``); seed: the ray sets' per-vertex rotation seed.
    """

    order: int
    n_rays: int
    offset: float
    seed: int = 0
    _rays: dict[tuple[int, str, int], RaySet] = field(default_factory=dict, init=False, repr=False)

    def rays(self, n_vertices: int, below_horizon: str, n_rays: int | None = None) -> RaySet:
        n_rays = int(n_rays or self.n_rays)
        key = (int(n_vertices), below_horizon, n_rays)
        if key not in self._rays:
            self._rays[key] = RaySet.make(n_rays, self.order, n_vertices, self.seed, below_horizon)
        return self._rays[key]

    def trace(self, scene: RayScene, points: np.ndarray, frames: np.ndarray, below_horizon: str,
              n_rays: int | None = None) -> np.ndarray:
        """``(V, C)`` float32 local-frame SH visibility of ``points (V, 3)`` with ``frames (V, 3, 3)``
        (``n_rays``: this receiver's rays per vertex, default the tracer's)."""
        points = np.asarray(points, dtype=np.float32)
        frames = np.ascontiguousarray(frames, dtype=np.float32)
        res = trace_frame(points, frames, None, self.rays(len(points), below_horizon, n_rays), self.offset,
                          scene=scene)
        return res.visibility

    def frame(self, meshes: list[tuple[np.ndarray, np.ndarray]], receivers: list[tuple]) -> list[np.ndarray]:
        """Truth of one frame: ``meshes`` ``[(vertices, faces)]`` form the scene; each receiver
        ``(points (V, 3), frames (V, 3, 3), below_horizon[, n_rays])`` gets ``(V, C)``."""
        v, f = merged_mesh(meshes)
        scene = RayScene(v, f)
        return [self.trace(scene, *r) for r in receivers]

"""Run-time SHEXP of sphere blockers through the run's ``shexp.onnx`` (onnxruntime, no torch).

The graph (:class:`prt_torch.shexp.ShexpVisibility`, exported by ``prt export``) maps receiver points
``(B, V, 3)``, their frames ``(B, V, 3, 3)`` (rows t, b, n), sphere centres ``(B, S, 3)`` and radii ``(B, S)``
to local-frame SH visibility ``(B, V, C)``. :class:`ShexpGraph` feeds it by input position, so it follows
the graph's own input names.

**Culling** (``cull``, default :data:`CULL_BELOW`): a sphere of radius ``r`` at distance ``d`` covers the
fraction ``(1 - cos a) / 2 ~ (r / d)^2 / 4`` of the sphere of directions. Receivers whose spheres cover less
than ``cull`` in total (``sum_s (r_s / d_s)^2 / 4``) are given the constant 1 without running the graph; their
visibility error is at most about that fraction (an L2 error ``<= sqrt(4 pi) * cull``). Characters far apart
therefore cost nothing and do not change each other at all.
"""

from __future__ import annotations

import os

import numpy as np

from prt_torch.errors import check
from prt_torch.runtime.session import OrtGraph
from prt_torch.scene.compose import constant_one

#: receivers whose spheres cover less than this fraction of their sphere of directions are left unoccluded
CULL_BELOW = 1e-4


def coverage(points: np.ndarray, centers: np.ndarray, radii: np.ndarray) -> np.ndarray:
    """``(B, V)`` approximate fraction of the sphere of directions the spheres cover at each point:
    ``sum_s min((r_s / d_s)^2, 1) / 4``. ``points (B, V, 3)``, ``centers (B, S, 3)``, ``radii (B, S)``."""
    p = np.asarray(points, dtype=np.float32)
    c = np.asarray(centers, dtype=np.float32)
    d2 = (p * p).sum(-1)[..., :, None] - 2.0 * (p @ c.transpose(0, 2, 1)) + (c * c).sum(-1)[..., None, :]
    r2 = np.square(np.asarray(radii, dtype=np.float32))[..., None, :]
    return 0.25 * np.minimum(r2 / np.maximum(d2, 1e-12), 1.0).sum(-1)


class ShexpGraph:
    """``shexp.onnx`` in onnxruntime. ``order``: the SH order of its output."""

    def __init__(self, path: str | os.PathLike[str], order: int, threads: int = 2) -> None:
        self.graph = OrtGraph(path, threads=threads)
        self.names = list(self.graph.inputs)
        check(len(self.names) == 4, f"{self.graph.path.name}: expected 4 inputs (points, frames, centers, radii), "
                                    f"got {self.names}")
        self.order = int(order)

    def __call__(self, points: np.ndarray, frames: np.ndarray, centers: np.ndarray, radii: np.ndarray,
                 checked: bool = False, cull: float = CULL_BELOW) -> np.ndarray:
        """``(B, V, C)`` float32 visibility of ``points (B, V, 3)`` with ``frames (B, V, 3, 3)`` under the spheres
        ``centers (B, S, 3)``, ``radii (B, S)``; no sphere (``S = 0``): the constant 1. ``cull``: see the module
        docstring (``0`` runs every receiver)."""
        b, v = points.shape[:2]
        one = np.broadcast_to(constant_one(self.order).astype(np.float32), (b, v, self.order ** 2))
        if centers.shape[1] == 0:
            return one.copy()
        if cull > 0 and b == 1:
            keep = np.flatnonzero(coverage(points, centers, radii)[0] >= cull)
            out = one.copy()
            if len(keep):
                out[0, keep] = self._run(points[:, keep], frames[:, keep], centers, radii, checked)[0]
            return out
        return self._run(points, frames, centers, radii, checked)

    def _run(self, points: np.ndarray, frames: np.ndarray, centers: np.ndarray, radii: np.ndarray,
             checked: bool) -> np.ndarray:
        feeds = dict(zip(self.names, (np.ascontiguousarray(points, dtype=np.float32),
                                      np.ascontiguousarray(frames, dtype=np.float32),
                                      np.ascontiguousarray(centers, dtype=np.float32),
                                      np.ascontiguousarray(radii, dtype=np.float32)), strict=True))
        if checked:
            return self.graph.run(feeds)[self.graph.outputs[0]]
        return self.graph.run_unchecked(feeds)[0]

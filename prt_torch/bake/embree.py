"""Ray queries against a triangle mesh through Intel Embree (``embreex``).

trimesh silently falls back to a pure-numpy tracer about 100x slower when ``embreex`` is
missing, so this module talks to ``embreex`` directly and stops with a :class:`PrtError` if it
cannot be imported. Every query is single-threaded and deterministic; parallelism comes from
running one scene per worker process.

Coordinates are world space, float32 (Embree's precision).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from prt_torch.errors import PrtError
from prt_torch.shapes import check_shape


def require_embreex() -> tuple[Any, Any]:
    """Import ``embreex``; returns ``(rtcore_scene, mesh_construction)`` or raises :class:`PrtError`."""
    try:
        from embreex import mesh_construction, rtcore_scene
    except Exception as exc:  # ImportError, or a broken shared library (OSError)
        raise PrtError(
            f"embreex is not importable ({type(exc).__name__}: {exc}); install it (pip install embreex): "
            "the pure-python fallback tracer is ~100x slower and is not used"
        ) from None
    return rtcore_scene, mesh_construction


@dataclass
class Hits:
    """Closest-hit records of ``N`` rays: ``prim (N,)`` int32 triangle id (-1: miss), barycentrics
    ``u, v (N,)`` float32 (hit point ``(1-u-v) p0 + u p1 + v p2``), distance ``t (N,)`` float32."""

    prim: np.ndarray
    u: np.ndarray
    v: np.ndarray
    t: np.ndarray


class RayScene:
    """An Embree scene of one posed triangle mesh.

    Args:
        vertices: ``(V, 3)`` positions (any float dtype; converted to float32).
        faces: ``(T, 3)`` integer vertex indices.
    """

    def __init__(self, vertices: np.ndarray, faces: np.ndarray) -> None:
        rtcore_scene, mesh_construction = require_embreex()
        vertices = np.asarray(vertices)
        faces = np.asarray(faces)
        check_shape(vertices, "V 3", name="mesh vertices")
        check_shape(faces, "T 3", name="mesh faces")
        if not np.issubdtype(faces.dtype, np.integer):
            raise PrtError(f"mesh faces must be an integer array of shape (T, 3), got {faces.dtype} {faces.shape}")
        if not np.isfinite(vertices).all():
            raise PrtError("mesh vertices contain NaN or Inf")
        if faces.size and (faces.min() < 0 or faces.max() >= len(vertices)):
            raise PrtError(f"mesh faces index vertices outside 0..{len(vertices) - 1}")
        self._scene = rtcore_scene.EmbreeScene()
        self._mesh = mesh_construction.TriangleMesh(
            self._scene, np.ascontiguousarray(vertices, dtype=np.float32), np.ascontiguousarray(faces, dtype=np.int32)
        )

    def occluded(self, origins: np.ndarray, directions: np.ndarray) -> np.ndarray:
        """Any-hit query: ``(N,)`` bool, True where the ray ``origins + s directions``, ``s > 0``, hits.

        Args:
            origins: ``(N, 3)`` float32 C-contiguous (other inputs are converted, costing a copy).
            directions: ``(N, 3)`` float32, need not be unit length.
        """
        o, d = _rays(origins, directions)
        return self._scene.run(o, d, query="OCCLUDED") != -1

    def intersect(self, origins: np.ndarray, directions: np.ndarray) -> Hits:
        """Closest-hit query of ``N`` rays (see :class:`Hits`)."""
        o, d = _rays(origins, directions)
        out = self._scene.run(o, d, query="INTERSECT", output=1)
        return Hits(prim=out["primID"], u=out["u"], v=out["v"], t=out["tfar"])


def _rays(origins: np.ndarray, directions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    o = np.ascontiguousarray(origins, dtype=np.float32)
    d = np.ascontiguousarray(directions, dtype=np.float32)
    dims = check_shape(o, "N 3", name="ray origins")
    check_shape(d, "N 3", name="ray directions", dims=dims)
    return o, d


def ray_offset(rest_vertices: np.ndarray, fraction: float) -> float:
    """Origin offset along the normal: ``fraction`` of the bounding-box diagonal of ``(V, 3)`` vertices."""
    v = np.asarray(rest_vertices, dtype=np.float64)
    if v.size == 0:
        raise PrtError("cannot scale the ray offset to an empty mesh")
    return float(fraction * np.linalg.norm(v.max(axis=0) - v.min(axis=0)))

"""The ground receiver: a square tessellated plane ``z = height`` with the constant vertex frame.

The ground is a receiver mesh like a character's: its vertices get local-frame SH visibility, shaded by the
same RPO path. Its vertex frame is the world frame (rows ``t = +x, b = +y, n = +z``), the same at every
vertex and every frame, so its local SH *is* world SH. numpy only (the player uses it).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from prt_torch.errors import check

#: the ground's vertex frame, rows (t, b, n) = (+x, +y, +z)
GROUND_FRAME = np.eye(3, dtype=np.float32)


@dataclass(frozen=True)
class Ground:
    """A tessellated square plane.

    Attributes:
        vertices: ``(G, 3)`` float32, ``G = (resolution + 1)^2``, row-major in y then x.
        faces: ``(2 resolution^2, 3)`` int64, counter-clockwise seen from above (normal ``+z``).
        height: the plane's ``z``; center: ``(2,)`` its xy centre; size: its side length.
        albedo: ``(3,)`` RGB diffuse albedo.
    """

    vertices: np.ndarray
    faces: np.ndarray
    height: float
    center: np.ndarray
    size: float
    albedo: np.ndarray

    @property
    def n_vertices(self) -> int:
        return int(self.vertices.shape[0])

    def frames(self, batch: tuple[int, ...] = ()) -> np.ndarray:
        """``(*batch, G, 3, 3)`` float32: the constant ground frame at every vertex."""
        return np.broadcast_to(GROUND_FRAME, (*batch, self.n_vertices, 3, 3))

    def normals(self) -> np.ndarray:
        """``(G, 3)`` float32 ``+z``."""
        return np.broadcast_to(GROUND_FRAME[2], (self.n_vertices, 3))


def make_ground(center: np.ndarray | tuple[float, float], size: float, height: float, resolution: int = 64,
                albedo: tuple[float, float, float] = (0.6, 0.6, 0.6)) -> Ground:
    """A ``size x size`` plane centred at ``center (x, y)``, at ``z = height``, ``resolution`` cells per side."""
    check(int(resolution) >= 1, f"ground resolution must be >= 1, got {resolution}")
    check(np.isfinite(size) and size > 0, f"ground size must be > 0, got {size}")
    check(np.isfinite(height), f"ground height must be finite, got {height}")
    c = np.asarray(center, dtype=np.float64).reshape(2)
    n = int(resolution)
    t = np.linspace(-0.5 * size, 0.5 * size, n + 1)
    gx, gy = np.meshgrid(c[0] + t, c[1] + t, indexing="xy")  # (n+1, n+1): row = y, column = x
    verts = np.stack([gx.ravel(), gy.ravel(), np.full(gx.size, height)], axis=-1).astype(np.float32)
    i, j = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")  # i: row (y), j: column (x)
    v00 = (i * (n + 1) + j).ravel()
    v01, v10, v11 = v00 + 1, v00 + n + 1, v00 + n + 2
    faces = np.concatenate([np.stack([v00, v01, v11], -1), np.stack([v00, v11, v10], -1)]).astype(np.int64)
    return Ground(verts, faces, float(height), c, float(size), np.asarray(albedo, dtype=np.float32).reshape(3))

"""Test meshes of the deform tests: a triangulated rectangular sheet (independent of prt_torch)."""

from __future__ import annotations

import numpy as np


def sheet(nx: int, ny: int, width: float = 1.0, height: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """A flat ``nx x ny``-vertex grid in the z = 0 plane, faces counter-clockwise seen from +z.

    Returns ``(vertices (nx * ny, 3) float64, faces (2 (nx - 1)(ny - 1), 3) int64)``.
    """
    xs, ys = np.meshgrid(np.linspace(0.0, width, nx), np.linspace(0.0, height, ny), indexing="xy")
    v = np.stack([xs.ravel(), ys.ravel(), np.zeros(nx * ny)], axis=1)
    idx = np.arange(nx * ny).reshape(ny, nx)
    a, b = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel()
    c, d = idx[1:, 1:].ravel(), idx[1:, :-1].ravel()
    faces = np.concatenate([np.stack([a, b, c], axis=1), np.stack([a, c, d], axis=1)]).astype(np.int64)
    return v, faces

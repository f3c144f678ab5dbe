"""Test scenes of the cone-tracing tests."""

from __future__ import annotations

import numpy as np


def slab_and_sphere(radius: float, height: float = 1.0, half: float = 2.0, thick: float = 0.05) -> tuple[
        np.ndarray, np.ndarray]:
    """A closed slab ``[-half, half]^2 x [-thick, 0]`` (top face at z = 0) and, if ``radius > 0``, a sphere of that
    radius centred ``height`` above the origin: ``(vertices (V, 3), faces (T, 3))``."""
    import trimesh

    b = trimesh.creation.box((2 * half, 2 * half, thick)).subdivide().subdivide().subdivide()
    v, f = [b.vertices - [0.0, 0.0, thick / 2]], [b.faces]
    if radius > 0:
        s = trimesh.creation.icosphere(4, radius)
        v.append(s.vertices + [0.0, 0.0, height])
        f.append(s.faces + len(v[0]))
    return np.concatenate(v), np.concatenate(f)

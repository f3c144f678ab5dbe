"""Ray directions of the bake: one shared low-discrepancy hemisphere set, rotated per vertex.

Every vertex traces the same ``R`` local directions ``d_r`` (a spherical-Fibonacci set on the
upper hemisphere ``z >= 0``, uniform in solid angle, so each ray carries the weight
``2 pi / R``), rotated about the local ``+z`` axis (the normal) by a per-vertex angle
``phi_v``. The angles come from the bake seed alone: they are the same in every frame, so the
Monte Carlo noise of a vertex is frozen over an animation instead of flickering (a model would
learn the flicker), while neighbouring vertices still decorrelate.
"""

from __future__ import annotations

import math

import numpy as np

from prt_torch.errors import PrtError

_GOLDEN_ANGLE = math.pi * (3.0 - math.sqrt(5.0))


def hemisphere_set(n: int) -> np.ndarray:
    """``(n, 3)`` float64 unit directions on ``z >= 0``, uniform in solid angle, low discrepancy.

    Spherical Fibonacci points: ``z_i = 1 - (i + 1/2) / n`` (equal-area bands), azimuth
    ``i * golden_angle``. Deterministic (no seed).
    """
    if not isinstance(n, int | np.integer) or n < 1:
        raise PrtError(f"number of hemisphere directions must be a positive integer, got {n!r}")
    i = np.arange(n, dtype=np.float64)
    z = 1.0 - (i + 0.5) / n
    r = np.sqrt(np.clip(1.0 - z * z, 0.0, None))
    phi = i * _GOLDEN_ANGLE
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=-1)


def vertex_angles(n_vertices: int, seed: int) -> np.ndarray:
    """``(V,)`` float64 per-vertex rotation angles in ``[0, 2 pi)`` about the local normal, from ``seed``."""
    if n_vertices < 0:
        raise PrtError(f"vertex count must be >= 0, got {n_vertices}")
    rng = np.random.default_rng(np.random.SeedSequence([int(seed) & 0xFFFFFFFF, 0x5EED_D1A5]))
    return rng.uniform(0.0, 2.0 * math.pi, size=n_vertices)


def rotated_frames(frames: np.ndarray, phi: np.ndarray) -> np.ndarray:
    """Fold the per-vertex z rotation into the frames: ``G_v = Rz(phi_v)^T F_v``.

    A local direction ``d`` (row vector) maps to the world direction ``d @ G_v =
    F_v^T Rz(phi_v) d``, i.e. ``d`` is rotated by ``phi_v`` about the normal and then expressed in
    world coordinates through the frame rows ``(t, b, n)``.

    Args:
        frames: ``(V, 3, 3)`` rows ``(t, b, n)``.
        phi: ``(V,)`` angles (radians).

    Returns:
        ``(V, 3, 3)`` in the dtype of ``frames``.
    """
    c = np.cos(phi).astype(frames.dtype)[:, None]
    s = np.sin(phi).astype(frames.dtype)[:, None]
    t, b, n = frames[:, 0], frames[:, 1], frames[:, 2]
    # Rz(phi)^T = [[c, s, 0], [-s, c, 0], [0, 0, 1]]
    return np.stack([c * t + s * b, c * b - s * t, n], axis=1)


def world_directions(local: np.ndarray, rotated: np.ndarray) -> np.ndarray:
    """All rays of a block of vertices with ONE matmul: ``(R, 3) x (V, 3, 3) -> (R, V, 3)``.

    ``out[r, v] = local[r] @ rotated[v]`` (ray-major order, C-contiguous), float32 if inputs are.
    """
    V = rotated.shape[0]
    B = rotated.transpose(1, 0, 2).reshape(3, 3 * V)
    return (local @ B).reshape(local.shape[0], V, 3)

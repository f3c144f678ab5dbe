"""Brute-force ray casting for tests: the independent reference of the bake's Embree rays."""

from __future__ import annotations

import numpy as np


def rays_hit(origin: np.ndarray, dirs: np.ndarray, tri: np.ndarray, t_min: float = 1e-6) -> np.ndarray:
    """``(R, T)`` whether each ray ``origin + t dirs`` (t > t_min) hits each triangle of ``tri (T, 3, 3)``:
    Moller-Trumbore, plain numpy, all rays x all triangles (the independent reference of the bake's Embree)."""
    e1, e2 = tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
    pv = np.cross(dirs[:, None], e2[None])  # (R, T, 3)
    det = np.einsum("rtk,tk->rt", pv, e1)
    ok = np.abs(det) > 1e-12
    inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)
    tv = origin - tri[:, 0]  # (T, 3)
    u = np.einsum("rtk,tk->rt", pv, tv) * inv
    qv = np.cross(tv, e1)  # (T, 3)
    v = np.einsum("rk,tk->rt", dirs, qv) * inv
    t = np.einsum("tk,tk->t", e2, qv)[None] * inv
    return ok & (u >= 0) & (v >= 0) & (u + v <= 1) & (t > t_min)

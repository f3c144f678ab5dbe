"""Rotation and rigid-transform helpers on numpy arrays (no torch).

Quaternions are ``(..., 4)`` in glTF order ``(x, y, z, w)`` (scalar last). Matrices are
``(..., 3, 3)`` rotations or ``(..., 4, 4)`` homogeneous transforms acting on column vectors
(``p' = M @ p``). Everything is float64 unless stated.
"""

from __future__ import annotations

import numpy as np

from prt_torch.errors import check
from prt_torch.exact import small_matmul
from prt_torch.shapes import check_shape

#: glTF/BVH (y up) -> library world (z up): ``(x, y, z) -> (x, -z, y)``.
Y_UP_TO_Z_UP = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])


def axis_angle_matrix(axis: np.ndarray, angle: np.ndarray | float) -> np.ndarray:
    """Rotation matrices about ``axis (3,)`` by ``angle (...)`` radians (Rodrigues) -> ``(..., 3, 3)``."""
    axis = np.asarray(axis, dtype=np.float64)
    axis = axis / np.sqrt(axis[0] * axis[0] + axis[1] * axis[1] + axis[2] * axis[2])  # no BLAS dot
    angle = np.asarray(angle, dtype=np.float64)
    c, s = np.cos(angle)[..., None, None], np.sin(angle)[..., None, None]
    x, y, z = axis
    k = np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])
    return np.eye(3) + s * k + (1.0 - c) * small_matmul(k, k)  # fixed order: feeds the bake


def quat_to_matrix(q: np.ndarray) -> np.ndarray:
    """Unit quaternions ``(..., 4)`` ``(x, y, z, w)`` -> rotation matrices ``(..., 3, 3)`` (normalises q)."""
    q = np.asarray(q, dtype=np.float64)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    x, y, z, w = np.moveaxis(q, -1, 0)
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)], -1),
        np.stack([2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)], -1),
        np.stack([2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)], -1),
    ], -2)


def matrix_to_quat(m: np.ndarray) -> np.ndarray:
    """Rotation matrices ``(..., 3, 3)`` -> unit quaternions ``(..., 4)`` ``(x, y, z, w)`` with ``w >= 0``."""
    from scipy.spatial.transform import Rotation

    m = np.asarray(m, dtype=np.float64)
    q = Rotation.from_matrix(m.reshape(-1, 3, 3)).as_quat().reshape(*m.shape[:-2], 4)
    return np.where(q[..., 3:4] < 0, -q, q)


def slerp(q0: np.ndarray, q1: np.ndarray, t: np.ndarray | float) -> np.ndarray:
    """Spherical linear interpolation of unit quaternions ``(..., 4)`` at ``t (...)`` (shortest arc)."""
    q0 = np.asarray(q0, dtype=np.float64)
    q1 = np.asarray(q1, dtype=np.float64)
    t = np.asarray(t, dtype=np.float64)[..., None]
    dot = np.sum(q0 * q1, axis=-1, keepdims=True)
    q1 = np.where(dot < 0, -q1, q1)
    dot = np.abs(dot)
    theta = np.arccos(np.clip(dot, -1.0, 1.0))
    sin_t = np.sin(theta)
    small = sin_t < 1e-8
    safe = np.where(small, 1.0, sin_t)
    a = np.where(small, 1.0 - t, np.sin((1.0 - t) * theta) / safe)
    b = np.where(small, t, np.sin(t * theta) / safe)
    q = a * q0 + b * q1
    return q / np.linalg.norm(q, axis=-1, keepdims=True)


def trs_matrix(translation: np.ndarray | None = None, rotation: np.ndarray | None = None,
               scale: np.ndarray | None = None) -> np.ndarray:
    """Compose ``T @ R @ S`` (glTF order) -> ``(..., 4, 4)``.

    ``translation (..., 3)``, ``rotation`` either quaternions ``(..., 4)`` or matrices ``(..., 3, 3)``,
    ``scale (..., 3)``; any may be ``None`` (identity). Leading shapes broadcast.
    """
    shapes = []
    if translation is not None:
        translation = np.asarray(translation, dtype=np.float64)
        shapes.append(translation.shape[:-1])
    rot = np.eye(3)
    if rotation is not None:
        rotation = np.asarray(rotation, dtype=np.float64)
        rot = quat_to_matrix(rotation) if rotation.shape[-1] == 4 else rotation
        shapes.append(rot.shape[:-2])
    if scale is not None:
        scale = np.asarray(scale, dtype=np.float64)
        shapes.append(scale.shape[:-1])
        rot = rot * scale[..., None, :]
    lead = np.broadcast_shapes(*shapes) if shapes else ()
    m = np.zeros((*lead, 4, 4))
    m[..., :3, :3] = rot
    if translation is not None:
        m[..., :3, 3] = translation
    m[..., 3, 3] = 1.0
    return m


def rotation_part(m: np.ndarray) -> np.ndarray:
    """Pure rotation of transforms ``(..., 4, 4)`` or ``(..., 3, 3)``: columns normalised (scale removed).

    Assumes no shear (true for TRS transforms); returns ``(..., 3, 3)``.
    """
    r = np.asarray(m, dtype=np.float64)[..., :3, :3]
    n = np.linalg.norm(r, axis=-2, keepdims=True)
    check(bool(np.all(n > 1e-12)), "transform has a zero scale: cannot extract its rotation")
    return r / n


def rigid_inverse(m: np.ndarray) -> np.ndarray:
    """Inverse of rigid transforms ``(..., 4, 4)`` (rotation + translation): ``[R^T | -R^T t]`` in closed form,
    the same bits on every machine (a transpose and :func:`prt_torch.exact.small_matmul`; no LAPACK)."""
    m = np.asarray(m, dtype=np.float64)
    check_shape(m, "... 4 4", name="rigid transforms")
    rt = np.swapaxes(m[..., :3, :3], -1, -2)
    check(bool(np.allclose(small_matmul(rt, m[..., :3, :3]), np.eye(3), atol=1e-9)),
          "rigid_inverse: the rotation part is not orthonormal")
    out = np.zeros_like(m)
    out[..., :3, :3] = rt
    out[..., :3, 3] = -small_matmul(rt, m[..., :3, 3:4])[..., 0]
    out[..., 3, 3] = 1.0
    return out

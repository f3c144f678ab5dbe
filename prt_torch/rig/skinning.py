"""Linear blend skinning in numpy (the run-time path: no torch).

``p'_v = sum_k w_vk S_{j_vk} [p_v; 1]`` with skin matrices ``S_j = world_j @ inverse_bind_j``.
Implementation: the sparse ``(V, K)`` indices/weights are expanded once into a dense ``(V, J)``
weight matrix ``W``; per frame the blended ``(V, 3, 4)`` matrices are one GEMM ``W @ S.reshape(J, 12)``.
Normals are the rest normals transformed by the same blended 3x3 block and renormalised (exact
for rigid joints; the inverse-transpose is not applied, which is the usual LBS approximation and
exact for rotations and uniform scale).
"""

from __future__ import annotations

import numpy as np

from prt_torch.errors import check


def check_skin_weights(joints: np.ndarray, weights: np.ndarray, num_joints: int, num_vertices: int | None = None,
                       tol: float = 1e-3) -> tuple[np.ndarray, np.ndarray]:
    """Validate ``joints (V, K)`` int and ``weights (V, K)``: in range, finite, >= 0, rows summing to 1 within ``tol``.

    Returns ``(joints int64, weights float32)``.
    """
    joints = np.asarray(joints)
    weights = np.asarray(weights)
    check(joints.ndim == 2 and weights.shape == joints.shape,
          f"skin joints and weights must both be (V, K), got {joints.shape} and {weights.shape}")
    if num_vertices is not None:
        check(joints.shape[0] == num_vertices,
              f"skin weights have {joints.shape[0]} rows but the mesh has {num_vertices} vertices")
    check(np.issubdtype(joints.dtype, np.integer), f"skin joint indices must be integers, got {joints.dtype}")
    check(bool(np.all((joints >= 0) & (joints < num_joints))), f"skin joint indices must lie in [0, {num_joints})")
    check(bool(np.all(np.isfinite(weights))), "skin weights contain NaN or inf")
    check(bool(np.all(weights >= -1e-6)), "skin weights must be non-negative")
    sums = weights.astype(np.float64).sum(axis=1)
    bad = np.abs(sums - 1.0) > tol
    check(not bool(np.any(bad)),
          f"skin weights must sum to 1 per vertex: {int(bad.sum())} vertices off by up to {np.abs(sums - 1).max():.3g}")
    return joints.astype(np.int64), weights.astype(np.float32)


def dense_weights(joints: np.ndarray, weights: np.ndarray, num_joints: int) -> np.ndarray:
    """Dense ``(V, J)`` float32 weight matrix from sparse ``joints (V, K)`` / ``weights (V, K)``."""
    v = joints.shape[0]
    w = np.zeros((v, num_joints), dtype=np.float32)
    np.add.at(w, (np.repeat(np.arange(v), joints.shape[1]), joints.reshape(-1)), weights.reshape(-1))
    return w


def skin(skin_mats: np.ndarray, dense_w: np.ndarray, rest_vertices: np.ndarray,
         rest_normals: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray | None]:
    """Skin a mesh: ``skin_mats (F, J, 4, 4)`` or ``(J, 4, 4)``, ``dense_w (V, J)``, ``rest_vertices (V, 3)``.

    Returns ``positions (F, V, 3)`` float32 and ``normals (F, V, 3)`` float32 unit (or ``None``
    without rest normals); with an unbatched ``(J, 4, 4)`` input the ``F`` axis is omitted.
    """
    m = np.asarray(skin_mats)
    single = m.ndim == 3
    if single:
        m = m[None]
    check(m.ndim == 4 and m.shape[-2:] == (4, 4) and m.shape[1] == dense_w.shape[1],
          f"skin matrices must be (F, {dense_w.shape[1]}, 4, 4), got {np.asarray(skin_mats).shape}")
    f, j = m.shape[:2]
    rows = m[:, :, :3, :].reshape(f, j, 12).astype(np.float32)
    blended = np.matmul(dense_w[None], rows).reshape(f, -1, 3, 4)  # (F, V, 3, 4)
    v = rest_vertices.astype(np.float32, copy=False)
    pos = (blended[..., 0] * v[None, :, 0:1] + blended[..., 1] * v[None, :, 1:2]
           + blended[..., 2] * v[None, :, 2:3] + blended[..., 3])
    nrm = None
    if rest_normals is not None:
        n = rest_normals.astype(np.float32, copy=False)
        nrm = blended[..., 0] * n[None, :, 0:1] + blended[..., 1] * n[None, :, 1:2] + blended[..., 2] * n[None, :, 2:3]
        nrm /= np.maximum(np.linalg.norm(nrm, axis=-1, keepdims=True), 1e-12)
    if single:
        return pos[0], (None if nrm is None else nrm[0])
    return pos, nrm

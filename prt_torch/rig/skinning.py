"""Linear blend skinning in numpy (the run-time path: no torch).

``p'_v = sum_k w_vk S_{j_vk} [p_v; 1]`` with skin matrices ``S_j = world_j @ inverse_bind_j``.
Implementation: the sparse ``(V, K)`` indices/weights are expanded once into a dense ``(V, J)``
weight matrix ``W``; per frame the blended ``(V, 3, 4)`` matrices are one product ``W @ S.reshape(J, 12)``, summed
over the joints in a fixed order (:func:`prt_torch.exact.fixed_order_matmul`: the bake is bit-exact across machines).
Normals are the rest normals transformed by the same blended 3x3 block and renormalised (exact
for rigid joints; the inverse-transpose is not applied, which is the usual LBS approximation and
exact for rotations and uniform scale).
"""

from __future__ import annotations

import numpy as np

from prt_torch.errors import check
from prt_torch.exact import fixed_order_matmul
from prt_torch.shapes import check_shape


def check_skin_weights(joints: np.ndarray, weights: np.ndarray, num_joints: int, num_vertices: int | None = None,
                       tol: float = 1e-3) -> tuple[np.ndarray, np.ndarray]:
    """Validate ``joints (V, K)`` int and ``weights (V, K)``: in range, finite, >= 0, rows summing to 1 within ``tol``.

    Returns ``(joints int64, weights float32)``.
    """
    joints = np.asarray(joints)
    weights = np.asarray(weights)
    dims = check_shape(joints, "V K", name="skin joints")
    check_shape(weights, "V K", name="skin weights", dims=dims)
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
         rest_normals: np.ndarray | None = None, dense_w_t: np.ndarray | None = None
         ) -> tuple[np.ndarray, np.ndarray | None]:
    """Skin a mesh: ``skin_mats (F, J, 4, 4)`` or ``(J, 4, 4)``, ``dense_w (V, J)``, ``rest_vertices (V, 3)``.

    Returns ``positions (F, V, 3)`` float32 and ``normals (F, V, 3)`` float32 unit (or ``None``
    without rest normals); with an unbatched ``(J, 4, 4)`` input the ``F`` axis is omitted.
    ``dense_w_t``: optional precomputed C-contiguous ``dense_w.T`` (J, V) float32 (speed only).
    The blended matrices are computed coefficient-major, ``(F, 12, V)``, so that every following
    operation runs on contiguous length-V rows.
    """
    m = np.asarray(skin_mats)
    single = m.ndim == 3
    if single:
        m = m[None]
    check(m.ndim == 4 and m.shape[-2:] == (4, 4) and m.shape[1] == dense_w.shape[1],
          f"skin matrices must be (F, {dense_w.shape[1]}, 4, 4), got {np.asarray(skin_mats).shape}")
    f, j = m.shape[:2]
    wt = np.ascontiguousarray(dense_w.T, dtype=np.float32) if dense_w_t is None else dense_w_t
    rows = np.ascontiguousarray(np.swapaxes(m[:, :, :3, :].reshape(f, j, 12), 1, 2), dtype=np.float32)
    b = fixed_order_matmul(rows, wt)  # (F, 12, V): b[:, 4*r + c] = blended M[r, c], the same bits everywhere
    vt = np.ascontiguousarray(rest_vertices.T, dtype=np.float32)  # (3, V)
    pos = np.empty((f, rest_vertices.shape[0], 3), dtype=np.float32)
    for r in range(3):
        pos[:, :, r] = b[:, 4 * r] * vt[0] + b[:, 4 * r + 1] * vt[1] + b[:, 4 * r + 2] * vt[2] + b[:, 4 * r + 3]
    nrm = None
    if rest_normals is not None:
        nt = np.ascontiguousarray(rest_normals.T, dtype=np.float32)
        n3 = np.empty((3, f, nt.shape[1]), dtype=np.float32)
        for r in range(3):
            n3[r] = b[:, 4 * r] * nt[0] + b[:, 4 * r + 1] * nt[1] + b[:, 4 * r + 2] * nt[2]
        inv = 1.0 / np.maximum(np.sqrt(n3[0] * n3[0] + n3[1] * n3[1] + n3[2] * n3[2]), 1e-12)
        nrm = np.empty_like(pos)
        for r in range(3):
            nrm[:, :, r] = n3[r] * inv
    if single:
        return pos[0], (None if nrm is None else nrm[0])
    return pos, nrm

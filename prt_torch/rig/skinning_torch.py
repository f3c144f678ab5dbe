"""Linear blend skinning in torch (differentiable, batched; same math as :mod:`prt_torch.rig.skinning`)."""

from __future__ import annotations

import torch


def dense_weights_torch(joints: torch.Tensor, weights: torch.Tensor, num_joints: int) -> torch.Tensor:
    """Dense ``(V, J)`` weights from ``joints (V, K)`` int64 and ``weights (V, K)``."""
    w = torch.zeros(joints.shape[0], num_joints, dtype=weights.dtype, device=weights.device)
    return w.scatter_add_(1, joints.long(), weights)


def lbs(skin_mats: torch.Tensor, joints: torch.Tensor, weights: torch.Tensor, rest_vertices: torch.Tensor,
        rest_normals: torch.Tensor | None = None) -> tuple[torch.Tensor, torch.Tensor | None]:
    """Linear blend skinning batched over frames.

    ``skin_mats (..., J, 4, 4)`` (``world @ inverse_bind``), ``joints (V, K)``, ``weights (V, K)``,
    ``rest_vertices (V, 3)``, optional ``rest_normals (V, 3)``. Returns ``positions (..., V, 3)`` and
    unit ``normals (..., V, 3)`` (rest normals through the blended 3x3 block, renormalised) or ``None``.
    """
    j = skin_mats.shape[-3]
    w = dense_weights_torch(joints, weights.to(skin_mats.dtype), j)  # (V, J)
    lead = skin_mats.shape[:-3]
    rows = skin_mats[..., :3, :].reshape(*lead, j, 12)
    blended = torch.matmul(w, rows).reshape(*lead, -1, 3, 4)  # (..., V, 3, 4)
    v = rest_vertices.to(skin_mats.dtype)
    pos = torch.einsum("...vij,vj->...vi", blended[..., :3], v) + blended[..., 3]
    nrm = None
    if rest_normals is not None:
        nrm = torch.einsum("...vij,vj->...vi", blended[..., :3], rest_normals.to(skin_mats.dtype))
        nrm = torch.nn.functional.normalize(nrm, dim=-1)
    return pos, nrm

"""Seed 001 eq. 5 per vertex: ``Gamma = V^T B T L`` with the factored BRDF matrix ``B ~ H G^T``.

Per vertex ``v`` with transfer matrix ``T_v (C, C)`` (:mod:`prt_torch.s001.bake`: global SH
lighting -> local SH incident radiance), frame ``F_v`` (rows ``t, b, n``) and world view direction ``e_v``
(unit, toward the viewer)::

    wo = F_v e_v,   l = T_v L (C, 3),   Gamma_v = tint * (y(wo)^T H) (G^T l)    (3,)

``H, G (C, k)`` from :func:`prt_torch.s001.brdf_matrix.factor` (``k = 4`` in the paper). The evaluation order keeps
the per-vertex work at ``3 C^2 + 3 k C + k C`` multiply-adds. For an unoccluded vertex this agrees with the
RPO shading (:func:`prt_torch.shade.rpo_shading.shade_rpo`) to the SH/SVD truncation errors of both.

Works on torch tensors (exportable ops: einsum, matmul) or numpy arrays (the same code path via the
backend's ``einsum``), returning the input's backend.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from prt_torch.errors import PrtError
from prt_torch.sh.basis import check_directions, is_torch, sh_basis
from prt_torch.shapes import check_shape


def _einsum(torch_backend: bool) -> Any:
    if torch_backend:
        import torch

        return torch.einsum
    return np.einsum


def shade_matrix(T: Any, L: Any, frames: Any, view_dirs: Any, H: Any, G: Any, tint: Any = None,
                 check: bool = True) -> Any:
    """Exit radiance ``(..., V, 3)`` of eq. 5 (see the module docstring).

    Args:
        T: ``(..., V, C, C)`` transfer matrices (``l_local = T @ L``).
        L: ``(C, 3)`` global SH lighting (RGB), or ``(..., C, 3)`` broadcast over vertices.
        frames: ``(..., V, 3, 3)`` vertex frames, rows ``(t, b, n)``.
        view_dirs: ``(..., V, 3)`` unit world directions toward the viewer.
        H, G: ``(C, k)`` view and light maps (:func:`prt_torch.s001.brdf_matrix.factor`).
        tint: optional ``(3,)`` RGB BRDF tint (default 1).
        check: validate shapes and values.

    Returns:
        ``(..., V, 3)`` in the backend (numpy or torch) and dtype of ``T``.
    """
    t = is_torch(T)
    if check:
        _check(T, L, frames, view_dirs, H, G, t)
    if t:
        import torch

        def cast(a: Any) -> Any:
            return torch.as_tensor(a, dtype=T.dtype, device=T.device)
    else:
        def cast(a: Any) -> Any:
            return np.asarray(a, dtype=T.dtype)
    L, frames, view_dirs, H, G = (cast(a) for a in (L, frames, view_dirs, H, G))
    es = _einsum(t)
    order = int(round(H.shape[0] ** 0.5))
    wo = es("...ij,...j->...i", frames, view_dirs)  # local view directions
    h = sh_basis(wo, order, check=False) @ H  # (..., V, k)
    lt = T @ L if L.ndim == 2 else es("...vij,...jc->...vic", T, L)  # (..., V, C, 3)
    g = es("ik,...ic->...kc", G, lt)  # (..., V, k, 3)
    out = es("...k,...kc->...c", h, g)
    return out if tint is None else out * cast(tint)


def _check(T: Any, L: Any, frames: Any, view_dirs: Any, H: Any, G: Any, t: bool) -> None:
    if not t and not isinstance(T, np.ndarray):
        raise PrtError(f"transfer matrices must be a numpy array or torch tensor, got {type(T).__name__}")
    check_shape(T, "... V C C", name="transfer matrices")
    C = int(T.shape[-1])
    order = int(round(C**0.5))
    if order * order != C:
        raise PrtError(f"{C} SH coefficients is not a square number n*n")
    for name, a in (("view map H", H), ("light map G", G)):
        if tuple(np.shape(a))[:1] != (C,) or len(np.shape(a)) != 2:
            raise PrtError(f"{name} must have shape ({C}, k), got {tuple(np.shape(a))}")
    if np.shape(H) != np.shape(G):
        raise PrtError(f"view map H and light map G must have the same shape, got {tuple(np.shape(H))} and "
                       f"{tuple(np.shape(G))}")
    if tuple(np.shape(L))[-2:] != (C, 3):
        raise PrtError(f"lighting must have shape (C={C}, 3), got {tuple(np.shape(L))}")
    lead = tuple(T.shape[:-2])
    if tuple(np.shape(frames)) != (*lead, 3, 3):
        raise PrtError(f"frames must have shape {(*lead, 3, 3)}, got {tuple(np.shape(frames))}")
    if tuple(np.shape(view_dirs)) != (*lead, 3):
        raise PrtError(f"view directions must have shape {(*lead, 3)}, got {tuple(np.shape(view_dirs))}")
    for name, a in (("transfer matrices", T), ("lighting", L), ("frames", frames)):
        finite = bool(a.isfinite().all()) if is_torch(a) else bool(np.isfinite(np.asarray(a)).all())
        if not finite:
            raise PrtError(f"{name} contain NaN or Inf")
    check_directions(view_dirs, "view directions")

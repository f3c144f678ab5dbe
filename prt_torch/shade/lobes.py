"""ZH lighting lobes rotated into per-vertex local frames (seed 003 sec. 5.4, [SLS05]).

A lobe ``(s_k, g_k)`` (world axis ``s_k (3,)``, band coefficients ``g_k (n, 3)`` RGB) has SH
coefficients ``g_kl y_lm(s_k)``. Rotating it into a vertex frame ``F`` (rows ``t, b, n`` in world
coordinates, so a world direction ``w`` has local coordinates ``F @ w``) only moves its axis:

    l_local[lm, c] = sum_k g_k[l, c] y_lm(F s_k)

which costs ``K`` SH evaluations per vertex instead of an SH rotation matrix.
"""

from __future__ import annotations

import numpy as np
import torch

from prt_torch.errors import PrtError
from prt_torch.sh.basis import band_of, check_directions, check_order, sh_basis
from prt_torch.shapes import check_shape


def check_frames(frames: torch.Tensor, name: str = "frames") -> None:
    """Validate ``(..., V, 3, 3)`` finite orthonormal frames (tolerance 1e-3)."""
    if not isinstance(frames, torch.Tensor):
        raise PrtError(f"{name} must be a torch tensor, got {type(frames).__name__}")
    check_shape(frames, "... V 3 3", name=name)
    f = frames.detach().to(torch.float64)
    if not torch.isfinite(f).all():
        raise PrtError(f"{name} contain NaN or Inf")
    if f.numel():
        err = float((f @ f.transpose(-1, -2) - torch.eye(3, dtype=torch.float64)).abs().max())
        if err > 1e-3:
            raise PrtError(f"{name} must be orthonormal (max |F F^T - I| = {err:.3g})")


def rotate_lobes_to_frames(lobe_dirs: torch.Tensor, lobe_coeffs: torch.Tensor, frames: torch.Tensor,
                           check: bool = True) -> torch.Tensor:
    """Local-frame SH lighting of ZH lobes at every vertex.

    Args:
        lobe_dirs: ``(K, 3)`` unit world lobe axes.
        lobe_coeffs: ``(K, n, 3)`` band coefficients per lobe, band and RGB channel.
        frames: ``(..., V, 3, 3)`` vertex frames, rows ``(t, b, n)`` in world coordinates.
        check: validate the inputs.

    Returns:
        ``l_local (..., V, C, 3)``, ``C = n*n``, in the dtype of ``frames``.
    """
    if check:
        for name, t in (("lobe_dirs", lobe_dirs), ("lobe_coeffs", lobe_coeffs)):
            if not isinstance(t, torch.Tensor):
                raise PrtError(f"{name} must be a torch tensor, got {type(t).__name__}")
        dims = check_shape(lobe_dirs, "K 3", name="lobe_dirs")
        check_directions(lobe_dirs, "lobe_dirs")
        check_shape(lobe_coeffs, "K n 3", name="lobe_coeffs", dims=dims)
        check_order(int(lobe_coeffs.shape[1]))
        if not torch.isfinite(lobe_coeffs).all():
            raise PrtError("lobe_coeffs contain NaN or Inf")
        check_frames(frames)
    order = int(lobe_coeffs.shape[1])
    dt = frames.dtype
    local = torch.einsum("...ab,kb->...ka", frames, lobe_dirs.to(dt))  # (..., V, K, 3)
    y = sh_basis(local, order, check=False)  # (..., V, K, C)
    band = torch.from_numpy(np.asarray(band_of(order))).to(frames.device)
    g = lobe_coeffs.to(dt)[:, band, :]  # (K, C, 3)
    return torch.einsum("...kc,kch->...ch", y, g)


def lobes_in_frames(lobes: object, frames: torch.Tensor, check: bool = True) -> torch.Tensor:
    """:func:`rotate_lobes_to_frames` for a lobe set object with numpy ``dirs (K, 3)`` and ``coeffs (K, n, 3)``
    (e.g. :class:`prt_torch.sh.zhfit.ZHLobes`); returns ``(..., V, C, 3)`` in the dtype of ``frames``."""
    if not (hasattr(lobes, "dirs") and hasattr(lobes, "coeffs")):
        raise PrtError(f"expected a lobe set with dirs and coeffs (e.g. ZHLobes), got {type(lobes).__name__}")
    if not isinstance(frames, torch.Tensor):
        raise PrtError(f"frames must be a torch tensor, got {type(frames).__name__}")
    dirs = torch.as_tensor(np.asarray(lobes.dirs), dtype=torch.float64)
    coeffs = torch.as_tensor(np.asarray(lobes.coeffs), dtype=torch.float64)
    if check:
        check_directions(dirs, "lobe dirs")
    dirs = dirs / dirs.norm(dim=-1, keepdim=True)  # exact unit length before the cast to frames' dtype
    return rotate_lobes_to_frames(dirs.to(frames.dtype), coeffs.to(frames.dtype), frames, check=check)

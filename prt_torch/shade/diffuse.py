"""Diffuse PRT shading (seed 000 sec. 3): radiance ``albedo * (L . t)``.

``t (..., V, C)`` is the world-frame diffuse transfer ``int V(w) max(n.w, 0)/pi y(w) dw`` (the ``1/pi`` is
inside ``t``, see ``docs/DESIGN.md``) and ``L (C, 3)`` the world-frame SH lighting, so an unshadowed
vertex under a uniform unit environment gets radiance ``albedo`` (irradiance ``pi``).
"""

from __future__ import annotations

import torch

from prt_torch.errors import PrtError
from prt_torch.shapes import check_shape


def shade_diffuse_prt(t: torch.Tensor, l: torch.Tensor, albedo: torch.Tensor | None = None,
                      check: bool = True) -> torch.Tensor:
    """Radiance ``(..., V, 3) = albedo * (t @ l)``.

    Args:
        t: ``(..., V, C)`` transfer vectors.
        l: ``(C, 3)`` RGB SH lighting (same frame as ``t``).
        albedo: optional RGB albedo broadcastable to ``(..., V, 3)``.
        check: validate shapes and finiteness.
    """
    if check:
        for name, x in (("transfer", t), ("lighting", l)):
            if not isinstance(x, torch.Tensor):
                raise PrtError(f"{name} must be a torch tensor, got {type(x).__name__}")
            if not torch.isfinite(x).all():
                raise PrtError(f"{name} contain NaN or Inf")
        dims = check_shape(t, "... V C", name="transfer")
        check_shape(l, "C 3", name="lighting", dims=dims)
    out = t @ l.to(t.dtype)
    return out if albedo is None else out * albedo

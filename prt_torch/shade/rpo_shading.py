"""RPO shading (seed 003 eq. 11), batched over vertices, in three algebraically equal evaluation orders.

All quantities are in each vertex's local frame (z = normal): visibility ``v (..., V, C)``, lighting
``l (..., V, C, 3)`` (e.g. from :func:`prt_torch.shade.lobes.rotate_lobes_to_frames`), view direction
``wo (..., V, 3)`` (unit, toward the viewer). With ``W_b = w_b . y(wo)``::

    L_c(wo) = tint_c sum_b W_b  l_c . (M_b v)                 "matrix":  k matrix-vector products (k C^2)
            = tint_c sum_b W_b  u_b . (l_c x v)               "product": 3 SH products, then k dots
            = tint_c        l_c . (u~ x v),  u~ = sum_b W_b u_b   "fused": ONE SH product for all k and RGB

(``Gamma`` is symmetric, so ``l . (M(u) v) = u . (l x v) = l . (u x v)``). ``product`` and ``fused`` form
the SH product as an outer product times the flattened dense Gaunt tensor (one GEMM);
``fused_gather`` is ``fused`` with the product over the Gaunt non-zeros only (dense index gathers,
:mod:`prt_torch.shade.triple_product`). No ``torch.sparse``: all export to ONNX. ``prt bench shade``
measures them: on CPU (order 4, k = 8, 1 thread) ``fused`` is fastest, the sparse gather the slowest.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Literal

import numpy as np
import torch
from torch import nn

from prt_torch.brdf.rpo import RPO
from prt_torch.errors import PrtError
from prt_torch.sh.basis import check_directions, sh_basis
from prt_torch.shade.triple_product import gather_product, gaunt_flat, gaunt_gather_tensors, outer_product_sh
from prt_torch.shapes import check_shape

Method = Literal["matrix", "product", "fused", "fused_gather"]
METHODS: tuple[str, ...] = ("matrix", "product", "fused", "fused_gather")


@dataclass
class RPOTensors:
    """Torch tensors of an RPO: ``M (k, C, C)``, ``u (k, C)``, ``w (k, C)``, ``tint (3,)``, the Gaunt
    gather tables ``I, J (C, P)`` int64, ``G (C, P)``, the flattened dense Gaunt tensor ``gamma (C*C, C)``
    and the SH ``order`` (a Python int)."""

    M: torch.Tensor
    u: torch.Tensor
    w: torch.Tensor
    tint: torch.Tensor
    I: torch.Tensor
    J: torch.Tensor
    G: torch.Tensor
    gamma: torch.Tensor
    order: int

    @classmethod
    def from_rpo(cls, rpo: RPO, dtype: Any = torch.float32, device: Any = None) -> RPOTensors:
        """Convert an :class:`~prt_torch.brdf.rpo.RPO` (numpy) to tensors of ``dtype`` on ``device``."""
        if not isinstance(rpo, RPO):
            raise PrtError(f"expected an RPO, got {type(rpo).__name__}")
        I, J, G = gaunt_gather_tensors(rpo.order, dtype, device)

        def t(a: np.ndarray) -> torch.Tensor:
            a = np.asarray(a)  # cached tables are read-only: copy those rather than alias them
            return torch.as_tensor(a if a.flags.writeable else a.copy(), dtype=dtype, device=device)

        return cls(t(rpo.M), t(rpo.u), t(rpo.w), t(rpo.tint), I, J, G, t(gaunt_flat(rpo.order)), rpo.order)


def _check_inputs(v: torch.Tensor, l_local: torch.Tensor, wo_local: torch.Tensor, c: int) -> None:
    for name, x in (("visibility", v), ("lighting", l_local), ("view directions", wo_local)):
        if not isinstance(x, torch.Tensor):
            raise PrtError(f"{name} must be a torch tensor, got {type(x).__name__}")
        if not torch.isfinite(x).all():
            raise PrtError(f"{name} contain NaN or Inf")
    check_shape(v, ("*", "V", c), name="visibility")
    check_shape(l_local, (*v.shape, 3), name="lighting")
    check_shape(wo_local, (*v.shape[:-1], 3), name="view directions")
    check_directions(wo_local, "view directions")


def shade_rpo(v: torch.Tensor, l_local: torch.Tensor, wo_local: torch.Tensor, rpo: RPOTensors | RPO,
              method: Method = "fused", check: bool = True) -> torch.Tensor:
    """Outgoing radiance ``(..., V, 3)`` of eq. 11 (see module docstring for the three methods).

    Args:
        v: ``(..., V, C)`` local-frame SH visibility.
        l_local: ``(..., V, C, 3)`` local-frame SH lighting (RGB).
        wo_local: ``(..., V, 3)`` unit view directions in the local frames.
        rpo: :class:`RPOTensors` (or an :class:`RPO`, converted to ``v``'s dtype).
        method: ``"matrix"``, ``"product"``, ``"fused"`` (default, fastest on CPU) or ``"fused_gather"``.
        check: validate the inputs.
    """
    if isinstance(rpo, RPO):
        rpo = RPOTensors.from_rpo(rpo, v.dtype, v.device)
    c = rpo.order * rpo.order
    if check:
        _check_inputs(v, l_local, wo_local, c)
        if method not in METHODS:
            raise PrtError(f"unknown RPO evaluation method {method!r}: expected one of {', '.join(METHODS)}")
    W = sh_basis(wo_local, rpo.order, check=False) @ rpo.w.T  # (..., V, k)
    if method == "matrix":
        p = torch.einsum("bij,...j->...bi", rpo.M, v)  # (..., V, k, C): M_b v
        t = torch.einsum("...bi,...ic->...bc", p, l_local)  # (..., V, k, 3)
        out = (W.unsqueeze(-1) * t).sum(-2)
    elif method == "product":
        lt = l_local.transpose(-1, -2)  # (..., V, 3, C)
        lv = outer_product_sh(lt, v.unsqueeze(-2).expand_as(lt), rpo.gamma)  # (..., V, 3, C)
        t = lv @ rpo.u.T  # (..., V, 3, k)
        out = (t * W.unsqueeze(-2)).sum(-1)
    elif method == "fused":
        u_view = W @ rpo.u  # (..., V, C)
        q = outer_product_sh(u_view, v, rpo.gamma)  # (..., V, C)
        out = (q.unsqueeze(-1) * l_local).sum(-2)
    else:  # fused_gather
        u_view = W @ rpo.u
        q = gather_product(u_view, v, rpo.I, rpo.J, rpo.G)
        out = (q.unsqueeze(-1) * l_local).sum(-2)
    return out * rpo.tint


class RPOShader(nn.Module):
    """``nn.Module`` for eq. 11 holding one RPO's tensors as buffers; swap the BRDF with :meth:`set_rpo`.

    ``forward(v (..., V, C), l_local (..., V, C, 3), wo_local (..., V, 3)) -> (..., V, 3)``. Inputs are not
    validated in ``forward`` (it is exported to ONNX); use :func:`shade_rpo` for a checked call.
    """

    def __init__(self, rpo: RPO, method: Method = "fused", dtype: Any = torch.float32) -> None:
        super().__init__()
        if method not in METHODS:
            raise PrtError(f"unknown RPO evaluation method {method!r}: expected one of {', '.join(METHODS)}")
        self.method: Method = method
        self._dtype = dtype
        t = RPOTensors.from_rpo(rpo, dtype)
        for name in ("M", "u", "w", "tint", "I", "J", "G", "gamma"):
            self.register_buffer(name, getattr(t, name))
        self.name = rpo.name
        self.order = rpo.order

    def set_rpo(self, rpo: RPO) -> None:
        """Swap in another RPO of the same order and term count (buffers are replaced in place)."""
        t = RPOTensors.from_rpo(rpo, self._dtype, self.u.device)
        if t.u.shape != self.u.shape:
            raise PrtError(f"set_rpo needs the same (k, C) = {tuple(self.u.shape)}, got {tuple(t.u.shape)}")
        for name in ("M", "u", "w", "tint"):
            getattr(self, name).copy_(getattr(t, name))
        self.name = rpo.name

    def tensors(self) -> RPOTensors:
        """The buffers as :class:`RPOTensors`."""
        return RPOTensors(self.M, self.u, self.w, self.tint, self.I, self.J, self.G, self.gamma, self.order)

    def forward(self, v: torch.Tensor, l_local: torch.Tensor, wo_local: torch.Tensor) -> torch.Tensor:
        return shade_rpo(v, l_local, wo_local, self.tensors(), self.method, check=False)

"""Sum of many rotated zonal functions, ``f = sum_s zh_to_sh(g_s, u_s)``, without the ``(..., S, C)`` tensor.

``zh_to_sh`` (:mod:`prt_torch.sh.zonal`) gives ``f_lm = g_l y_lm(u)``; summed over ``S`` lobes per receiver that
is ``f_lm = K_lm sum_s g_l(s) Q_lm(z_s) T_m(x_s, y_s)`` with the factors of :func:`prt_torch.sh.basis.sh_basis`:
``T_m = Re/Im (x + i y)^m`` and ``Q_lm`` the associated Legendre polynomial without ``sin^m``. Here:

* ``Q_lm`` is written ``lead_lm * Qhat_lm`` with ``Qhat`` monic (coefficients from the same three-term
  recurrence as ``sh_basis``, in float64 numpy); ``lead * K`` multiplies the ``(..., C)`` result once, after the
  sum over ``S``, so the per-lobe work is only ``Qhat`` (0-2 operations each), ``g_l Qhat_lm`` and ``T_m``;
* every coefficient is reduced over ``S`` as soon as it is formed: the largest live tensors are ``(..., S)``.

At order 4 that is ~45 elementwise operations and 16 reductions on ``(..., S)`` arrays per receiver
instead of a ``(..., S, 16)`` basis and a ``(..., S, 16)`` product (tested against ``zh_to_sh(...).sum``).
Torch (ONNX-exportable); the factor tables (:func:`prt_torch.scene.shexp_kernel.monic_legendre`) are numpy, shared
with the scene's compiled kernel generated from them.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from prt_torch.scene.shexp_kernel import lobe_pairs, monic_legendre

if TYPE_CHECKING:
    import torch


def zonal_sum(x: torch.Tensor, y: torch.Tensor, z: torch.Tensor, g: list[torch.Tensor], order: int) -> torch.Tensor:
    """``sum_s zh_to_sh(g[:, s], u_s)`` over the last axis (module doc).

    Args:
        x, y, z: ``(..., S)`` components of unit axes ``u_s``.
        g: ``order`` tensors ``(..., S)``: the band coefficients ``g_l`` of each lobe (project ZH convention).
        order: ``n`` (1..16, a Python int).

    Returns:
        ``(..., n*n)`` SH coefficients (flat index ``l (l+1) + m``), dtype of ``x``.
    """
    import torch  # here: the module's tables serve the torch-free compiled kernel (prt_torch.scene.shexp_kernel)

    qhat, scale = monic_legendre(order)
    zp = [None, z]  # powers of z, built on demand
    c, s = [None, x], [None, y]  # Re, Im (x + i y)^m
    for _m in range(2, order):
        c.append(c[-1] * x - s[-1] * y)
        s.append(s[-1] * x + c[-2] * y)
    cols: list[torch.Tensor | None] = [None] * (order * order)
    for (l, m), q in zip(lobe_pairs(order), qhat, strict=True):
        w = g[l]
        if len(q) > 1:  # Qhat = z^d + sum_j q_j z^j (j of d's parity): weight it term by term
            while len(zp) < len(q):
                zp.append(zp[-1] * z)
            acc = zp[len(q) - 1]
            for j in range(len(q) - 1):
                if q[j] != 0.0:
                    acc = acc + q[j] if j == 0 else acc + q[j] * zp[j]
            w = w * acc
        if m == 0:
            cols[l * (l + 1)] = w.sum(-1)
        else:
            cols[l * (l + 1) + m] = (w * c[m]).sum(-1)
            cols[l * (l + 1) - m] = (w * s[m]).sum(-1)
    out = torch.stack(cols, dim=-1)  # type: ignore[arg-type]
    return out * torch.as_tensor(scale, dtype=out.dtype, device=out.device)

"""Fast SH rotation of many vectors by many frames through z-rotations (the "fast SH Z-rotations" of seed 003).

A rotation ``F = R_z(a) R_y(b) R_z(c)`` (ZYZ Euler angles) has the SH rotation
``D(F) = Z(a) X^T Z(b) X Z(c)`` with ``X = D(R_x(pi/2))`` (``R_y(b) = R_x(-pi/2) R_z(b) R_x(pi/2)``), where a
z-rotation ``Z(t)`` only mixes each ``(m, -m)`` pair of a band (angle ``m t``; in this basis, coefficients of
``f(R_z(t)^T w)``: ``c'_m = c_m cos mt - c_-m sin mt``, ``c'_-m = c_-m cos mt + c_m sin mt``). Applied to a
vector it costs three element-wise z-rotations and two products with the fixed block-diagonal ``X`` per
vertex, instead of building ``D(F)`` by the Ivanic recurrence. ``X`` itself comes from
:func:`prt_torch.sh.rotation.sh_rotation` (the project's rule); tests check the result against it.

Euler angles (robust at ``b = 0``, where ``a`` and ``c`` are not separately defined): from the third row
``n = (-sin b cos c, sin b sin c, cos b)``, ``b = acos(n_z)``, ``c = atan2(n_y, -n_x)``; then
``Q = F (R_y(b) R_z(c))^T`` is a z-rotation up to rounding and ``a = atan2(Q_10, Q_00)``.
"""

from __future__ import annotations

import numpy as np
import torch

from prt_torch.sh.basis import check_order
from prt_torch.sh.rotation import sh_rotation


def zyz_angles(frames: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """``(a, b, c)`` each ``(V,)`` with ``frames (V, 3, 3) = R_z(a) R_y(b) R_z(c)`` (rotations, det +1)."""
    n = frames[:, 2]
    b = torch.acos(n[:, 2].clamp(-1.0, 1.0))
    c = torch.atan2(n[:, 1], -n[:, 0])
    cb, sb, cc, sc = torch.cos(b), torch.sin(b), torch.cos(c), torch.sin(c)
    # columns 0 and 1 of (R_y(b) R_z(c))^T: first two rows of R_y(b) R_z(c)
    # R_y(b) R_z(c) rows: r0 = (cb cc, -cb sc, sb), r1 = (sc, cc, 0)
    r0 = torch.stack([cb * cc, -cb * sc, sb], dim=-1)
    q00 = (frames[:, 0] * r0).sum(-1)
    q10 = (frames[:, 1] * r0).sum(-1)
    a = torch.atan2(q10, q00)
    return a, b, c


class ZRotator:
    """Rotates SH vectors by per-vertex rotations with z-rotations (module docstring).

    Vectors are vertex-last ``(C, V)`` (every step is then a few whole-row operations per ``(l, m)`` pair).

    Args:
        order: SH order ``n``. dtype: torch dtype of the fixed matrices.
    """

    def __init__(self, order: int, dtype: torch.dtype = torch.float32) -> None:
        check_order(order)
        self.order = int(order)
        # rows of +m and -m of every band l >= m, per m >= 1
        self.pairs = [(torch.as_tensor([l * (l + 1) + m for l in range(m, order)]),
                       torch.as_tensor([l * (l + 1) - m for l in range(m, order)])) for m in range(1, order)]
        rx = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])  # R_x(pi/2)
        x = sh_rotation(rx, order)
        self.x = torch.as_tensor(x, dtype=dtype)
        self.x_t = torch.as_tensor(x.T.copy(), dtype=dtype)

    def rotate_z(self, v: torch.Tensor, angle: torch.Tensor) -> torch.Tensor:
        """``(C, V)`` coefficients of ``f(R_z(angle)^T w)`` for ``v (C, V)``, ``angle (V,)``."""
        out = v.clone()
        for m, (ip, im) in enumerate(self.pairs, start=1):
            cm, sm = torch.cos(m * angle), torch.sin(m * angle)
            vp, vm = v[ip], v[im]
            out[ip] = vp * cm - vm * sm
            out[im] = vm * cm + vp * sm
        return out

    def __call__(self, v: torch.Tensor, frames: torch.Tensor) -> torch.Tensor:
        """``D(F) v`` for ``v (C, V)`` and rotations ``frames (V, 3, 3)`` -> ``(C, V)``."""
        a, b, c = zyz_angles(frames.to(v.dtype))
        v = self.x @ self.rotate_z(v, c)
        v = self.x_t @ self.rotate_z(v, b)
        return self.rotate_z(v, a)

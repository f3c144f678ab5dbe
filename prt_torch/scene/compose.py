"""The cast-shadow composition rule (ONE place: the player, ``prt compare`` and the tests use it).

Seed 003 (sec. 2, 7): RPOs shade any visibility, and visibility from independent occluders multiplies.
In a scene with a ground plane and characters ``k = 1..K``:

* **ground** vertex visibility = the SHEXP visibility (Ren 2006) of ALL characters' posed blocker spheres at
  the ground vertex, in the ground frame (= world frame). It is the constant 1 below the ground's horizon
  (the ground's convention ``"one"``, :mod:`prt_torch.scene.truth`).
* **character k** vertex visibility = ``v_self (x) O_ground (x) O_others`` where ``v_self`` is the run's
  learned self-visibility, ``O_others`` the SHEXP visibility of the OTHER characters' spheres at the vertex
  (in its vertex frame) and ``O_ground`` the ground as a half-space occluder: the SH of the indicator of the
  directions above the ground plane (``w . up > 0``), a ZH about ``up`` rotated into each vertex frame
  (``zh_to_sh(hemisphere_zh(n), F @ up)``; the band coefficients are precomputed per order). ``(x)`` is the
  SH triple product projected back to order ``n`` (:func:`prt_torch.sh.product.sh_product`); products are
  applied left to right.

**Below the horizon** (``bake.below_horizon``). The bake shoots no ray below a vertex's horizon; there the
truth is 0 (``"zero"``) or 1 (``"one"``) whatever other bodies do. With ``H`` the upper-hemisphere
indicator of the vertex frame, ``hs`` / ``hx`` "hit by self / by occluder x":

* ``"zero"``: ``v_self = H (1 - hs)``, truth ``= H (1 - hs)(1 - hx) = v_self * X`` (``H^2 = H``): the
  external occluder ``X`` multiplies as it is.
* ``"one"``: ``v_self = 1 - H hs``, truth ``= 1 - H (1 - (1 - hs)(1 - hx))``, which equals
  ``v_self * (1 - H (1 - X))``: the occluder enters masked to the upper hemisphere,
  ``O = 1 - H (1 - X)``, computed as ``e - P_H (e - X)`` with ``e = sqrt(4 pi) e_0`` (the constant 1) and
  ``P_H`` the constant product matrix of the hemisphere indicator about the local ``+z``
  (:func:`prt_torch.sh.product.mask_below_horizon`, the rule the SHEXP graph applies too).

Both identities are exact in exact arithmetic, so the composition agrees with the whole-scene Embree truth
up to the learned model's error, the sphere approximation, SH truncation of the products (order ``n``) and
the infinite-plane approximation of a finite ground. numpy only.
"""

from __future__ import annotations

import numpy as np

from prt_torch.conventions import BELOW_HORIZON
from prt_torch.errors import check
from prt_torch.sh.product import mask_below_horizon, sh_product
from prt_torch.sh.zonal import hemisphere_zh, zh_to_sh

#: the world up axis (z up, docs/DESIGN.md): the ground plane's normal
UP = np.array([0.0, 0.0, 1.0])


def constant_one(order: int) -> np.ndarray:
    """``(C,)`` float64 SH of the constant 1: ``sqrt(4 pi) e_0``."""
    out = np.zeros(order * order)
    out[0] = np.sqrt(4.0 * np.pi)
    return out




def halfspace_visibility(frames: np.ndarray, order: int, up: np.ndarray = UP) -> np.ndarray:
    """``(..., V, C)`` float32: the ground plane as a half-space occluder in each vertex frame.

    The indicator of the directions above the plane (``w . up > 0``) is a ZH about ``up``; in a vertex frame
    ``F`` (rows t, b, n) its axis is ``F @ up``. ``frames``: ``(..., V, 3, 3)``.
    """
    g = hemisphere_zh(order)
    f = np.asarray(frames, dtype=np.float64)
    axis = f @ np.asarray(up, dtype=np.float64)
    axis /= np.maximum(np.linalg.norm(axis, axis=-1, keepdims=True), 1e-12)
    return zh_to_sh(g, axis, check=False).astype(np.float32)


class Composer:
    """Composes a receiver's self-visibility with external occluders (module docstring).

    Args:
        order: SH order ``n``.
        below_horizon: the receiver's dataset convention, ``"zero"`` or ``"one"``.
    """

    def __init__(self, order: int, below_horizon: str = "zero") -> None:
        check(below_horizon in BELOW_HORIZON, f"below_horizon must be one of {list(BELOW_HORIZON)}, "
                                              f"got {below_horizon!r}")
        self.order = int(order)
        self.below_horizon = below_horizon

    def occluder(self, x: np.ndarray) -> np.ndarray:
        """The factor an external occluder's visibility ``x (..., C)`` enters the product with: ``x`` itself
        (``"zero"``) or ``1 - H (1 - x)`` (``"one"``)."""
        x = np.asarray(x, dtype=np.float32)
        if self.below_horizon == "zero":
            return x
        return mask_below_horizon(x, self.order, "one").astype(np.float32)

    def compose(self, self_vis: np.ndarray, occluders: list[np.ndarray]) -> np.ndarray:
        """``self_vis (..., V, C)`` times (SH product, left to right) every occluder visibility
        ``(..., V, C)`` (each passed through :meth:`occluder`)."""
        out = np.asarray(self_vis, dtype=np.float32)
        for x in occluders:
            out = sh_product(out, self.occluder(x), check=False).astype(np.float32, copy=False)
        return out

    def in_scene(self, self_vis: np.ndarray, frames: np.ndarray, ground: bool = True,
                 others: np.ndarray | None = None) -> np.ndarray:
        """A character's in-scene visibility: ``v_self (x) O_ground (x) O_others`` (``ground``: the scene has a
        floor; ``others``: the SHEXP visibility of the other characters' spheres, ``None`` when there are none).
        ``frames (..., V, 3, 3)`` the vertex frames."""
        occ = [halfspace_visibility(frames, self.order)] if ground else []
        if others is not None:
            occ.append(others)
        return self.compose(self_vis, occ)

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
the infinite-plane approximation of a finite ground.

The products run in one compiled pass (:func:`sh_products`: the Gaunt tensor's nonzeros, 353 at order 4, per
vertex; numba) and only at the vertices an occluder reaches: an occluder equal to the constant 1 (the other
characters' visibility where :class:`prt_torch.scene.shexp_kernel.CompiledShexp` culled every sphere) leaves the
product unchanged and is skipped (``rows``). numpy + numba.
"""

from __future__ import annotations

import functools

import numpy as np

from prt_torch.conventions import BELOW_HORIZON
from prt_torch.errors import check
from prt_torch.sh.product import dense_gaunt, mask_below_horizon
from prt_torch.sh.zonal import hemisphere_zh, zh_to_sh

#: the world up axis (z up, docs/DESIGN.md): the ground plane's normal
UP = np.array([0.0, 0.0, 1.0])


def constant_one(order: int) -> np.ndarray:
    """``(C,)`` float64 SH of the constant 1: ``sqrt(4 pi) e_0``."""
    out = np.zeros(order * order)
    out[0] = np.sqrt(4.0 * np.pi)
    return out




@functools.cache
def gaunt_nonzeros(order: int) -> tuple[np.ndarray, np.ndarray]:
    """``(index (K, 3) int64, value (K,) float64)``: the nonzero Gaunt coefficients ``Gamma_ijk``
    (:func:`prt_torch.sh.product.dense_gaunt`) of order ``order``."""
    g = dense_gaunt(order)
    idx = np.argwhere(np.abs(g) > 1e-12)
    return idx, g[tuple(idx.T)]


def _product_lines(order: int, a: str, b: str) -> list[str]:
    """Generated statements: ``o0 .. o{C-1}`` = the Gaunt product of the scalars ``{a}j`` and ``{b}k``."""
    idx, val = gaunt_nonzeros(order)
    terms: list[list[str]] = [[] for _ in range(order * order)]
    for (i, j, k), v in zip(idx.tolist(), val.tolist(), strict=True):
        terms[i].append(f"{v!r} * {a}{j} * {b}{k}")
    return [f"o{i} = {' + '.join(t) if t else '0.0'}" for i, t in enumerate(terms)]


@functools.cache
def _product_kernels(order: int, below_horizon: str = "zero") -> tuple:
    """The compiled ``(products, ground_products)`` kernels at ``order`` (generated, cached on disk); the half-space
    of ``ground_products`` enters as :meth:`Composer.occluder` does in the ``below_horizon`` convention."""
    from prt_torch.scene.shexp_kernel import generated, sh_basis_lines
    from prt_torch.sh.zonal import hemisphere_zh

    c = order * order
    ind = " " * 8
    load_a = [f"a{j} = a[r, {j}]" for j in range(c)]
    load_b = [f"b{j} = b[r, {j}]" for j in range(c)]
    store = [f"out[r, {i}] = o{i}" for i in range(c)]
    g = hemisphere_zh(order)
    # the half-space above the floor: ZH about up = (0, 0, 1), in the vertex frame F (rows t, b, n): F @ up
    axis = ["ux = frames[r, 0, 2]", "uy = frames[r, 1, 2]", "uz = frames[r, 2, 2]",
            "un = 1.0 / max(np.sqrt(ux * ux + uy * uy + uz * uz), 1e-12)"]
    basis = sh_basis_lines(order, "ux * un", "uy * un", "uz * un")
    half = [f"h{l * l + i} = {float(g[l])!r} * y{l * l + i}" for l in range(order) for i in range(2 * l + 1)]
    if below_horizon == "zero":
        half += [f"b{i} = h{i}" for i in range(c)]
    else:  # "one": e - P_H (e - h) = (e - P_H e) + P_H h, P_H the hemisphere product matrix (constant)
        p_h = mask_below_horizon(np.eye(c), order, "one") - mask_below_horizon(np.zeros(c), order, "one")[None]
        e0 = mask_below_horizon(np.zeros(c), order, "one")
        for i in range(c):
            terms = [repr(float(e0[i]))] + [f"{float(p_h[j, i])!r} * h{j}" for j in range(c) if abs(p_h[j, i]) > 1e-12]
            half.append(f"b{i} = {' + '.join(terms)}")
    src = f'''"""Generated by prt_torch.scene.compose (SH products, order {order}, {below_horizon}); do not edit."""
import numba
import numpy as np


@numba.njit(cache=True, parallel=True, fastmath=True, nogil=True)
def products(a, b, rows, out):
    for t in numba.prange(rows.shape[0]):
        r = rows[t]
{chr(10).join(ind + x for x in load_a + load_b + _product_lines(order, "a", "b") + store)}


@numba.njit(cache=True, parallel=True, fastmath=True, nogil=True)
def ground_products(a, frames, out):
    for r in numba.prange(a.shape[0]):
{chr(10).join(ind + x for x in load_a + axis + basis + half + _product_lines(order, "a", "b") + store)}
'''
    name = f"products{order}{below_horizon}"
    return generated(name, src, "products"), generated(name, src, "ground_products")


def sh_products(a: np.ndarray, b: np.ndarray, rows: np.ndarray | None = None) -> np.ndarray:
    """``(..., C)`` float32 projected SH products ``a x b`` of ``a, b (..., C)`` (the same numbers as
    :func:`prt_torch.sh.product.sh_product`, one compiled pass); ``rows``: flat indices into ``a``'s rows where
    ``b`` is not the constant 1 (elsewhere the result is ``a``); ``None``: every row."""
    shape = np.broadcast_shapes(np.shape(a), np.shape(b))
    c = shape[-1]
    aa = np.ascontiguousarray(np.broadcast_to(a, shape), dtype=np.float32).reshape(-1, c)
    bb = np.ascontiguousarray(np.broadcast_to(b, shape), dtype=np.float32).reshape(-1, c)
    rr = np.arange(aa.shape[0]) if rows is None else np.asarray(rows, dtype=np.int64)
    out = aa.copy() if rows is not None else np.empty_like(aa)
    if rr.shape[0]:
        _product_kernels(int(round(np.sqrt(c))))[0](aa, bb, rr, out)
    return out.reshape(shape)


def ground_products(a: np.ndarray, frames: np.ndarray, below_horizon: str = "zero") -> np.ndarray:
    """``(..., V, C)`` float32 ``a (x) O_ground`` (the SH product) of ``a (..., V, C)`` and the floor's half-space
    (:func:`halfspace_visibility` of vertex frames ``(..., V, 3, 3)``, entering as :meth:`Composer.occluder` does in
    the ``below_horizon`` convention) in one compiled pass (the half-space built in it)."""
    shape = np.shape(a)
    c = shape[-1]
    aa = np.ascontiguousarray(a, dtype=np.float32).reshape(-1, c)
    fr = np.ascontiguousarray(np.broadcast_to(frames, (*shape[:-1], 3, 3)), dtype=np.float32).reshape(-1, 3, 3)
    out = np.empty_like(aa)
    if aa.shape[0]:
        _product_kernels(int(round(np.sqrt(c))), below_horizon)[1](aa, fr, out)
    return out.reshape(shape)


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

    def compose(self, self_vis: np.ndarray, occluders: list[np.ndarray],
                rows: list[np.ndarray | None] | None = None) -> np.ndarray:
        """``self_vis (..., V, C)`` times (SH product, left to right) every occluder visibility
        ``(..., V, C)`` (each passed through :meth:`occluder`); ``rows``: per occluder the flat row indices where
        it is not the constant 1 (:func:`sh_products`; ``None``: everywhere)."""
        out = np.asarray(self_vis, dtype=np.float32)
        rows = rows if rows is not None else [None] * len(occluders)
        for x, r in zip(occluders, rows, strict=True):
            if r is not None:
                flat = np.asarray(x, dtype=np.float32).reshape(-1, x.shape[-1])
                occ = np.broadcast_to(constant_one(self.order).astype(np.float32), flat.shape).copy()
                occ[r] = self.occluder(flat[r])
                out = sh_products(out, occ.reshape(x.shape), r)
            else:
                out = sh_products(out, self.occluder(x))
        return out

    def in_scene(self, self_vis: np.ndarray, frames: np.ndarray, ground: bool = True,
                 others: np.ndarray | None = None, others_rows: np.ndarray | None = None) -> np.ndarray:
        """A character's in-scene visibility: ``v_self (x) O_ground (x) O_others`` (``ground``: the scene has a
        floor; ``others``: the SHEXP visibility of the other characters' spheres, ``None`` when there are none;
        ``others_rows``: the flat vertex indices where ``others`` is not the constant 1, ``None``: all).
        ``frames (..., V, 3, 3)`` the vertex frames."""
        out = ground_products(self_vis, frames, self.below_horizon) if ground else np.asarray(self_vis, np.float32)
        if others is None:
            return out
        return self.compose(out, [others], [others_rows])

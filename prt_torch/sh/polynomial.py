"""The real SH basis as polynomials of the direction's components (numpy; the run-time graphs and kernels).

``sh_basis(d) = monomials(d) @ coeffs`` exactly for any ``d`` (:func:`sh_polynomial`), with the monomials listed
degree-major so that each one of degree ``>= 2`` is a lower one times one component (:func:`monomial_recursion`):
the ONNX graphs (:class:`prt_torch.export.graphs.SHPolynomial`) and the compiled frame path
(:mod:`prt_torch.player.frame_kernels`) build them the same way.
"""

from __future__ import annotations

import itertools
from functools import cache

import numpy as np

from prt_torch.sh.basis import check_order, sh_basis


@cache
def sh_polynomial(order: int) -> tuple[np.ndarray, np.ndarray]:
    """Exact polynomial form of the real SH basis of ``order``.

    Returns:
        ``exponents (P, 3)`` int64 - monomials ``x^a y^b z^c`` with ``a + b + c < order``;
        ``coeffs (P, C)`` float64 - so that ``sh_basis(d) = monomials(d) @ coeffs`` for any ``d`` (the basis of
        :mod:`prt_torch.sh.basis` is a polynomial of degree ``< order`` in x, y, z, recovered here by an exact
        least-squares solve on random non-unit points).
    """
    check_order(order)
    exps = np.array([e for e in itertools.product(range(order), repeat=3) if sum(e) < order], dtype=np.int64)
    pts = np.random.default_rng(0).uniform(-1.0, 1.0, size=(4 * len(exps) + 16, 3))
    mono = np.prod(pts[:, None, :] ** exps[None, :, :], axis=-1)
    target = sh_basis(pts, order, check=False)
    coeffs, *_ = np.linalg.lstsq(mono, target, rcond=None)
    coeffs[np.abs(coeffs) < 1e-12] = 0.0
    return exps, coeffs


@cache
def monomial_recursion(order: int) -> tuple[list[tuple[int, int, int]], np.ndarray, np.ndarray, np.ndarray]:
    """The degree-major monomials of ``order`` and how each is built.

    Returns ``(exps, parent (P,), comp (P,), coeffs_t (C, P))``: ``exps`` lists the exponents ``(a, b, c)`` in the
    order ``1, x, y, z``, then degree by degree (each degree's exponents in descending order); monomial ``p >= 4`` is
    monomial ``parent[p]`` (of the degree below) times component ``comp[p]`` (0, 1, 2 = x, y, z; entries ``< 4``
    are -1); ``coeffs_t (C, P)`` float64 is :func:`sh_polynomial`'s table in that order, ``y = coeffs_t @ mono``.
    """
    exps, coeffs = sh_polynomial(order)
    all_exps = [tuple(int(v) for v in e) for e in exps]
    levels: list[list[tuple[int, int, int]]] = [[(0, 0, 0)], [(1, 0, 0), (0, 1, 0), (0, 0, 1)]][:order]
    parent, comp = [-1] * sum(len(lv) for lv in levels), [-1] * sum(len(lv) for lv in levels)
    start = len(parent) - (len(levels[-1]) if order > 1 else 0)
    for deg in range(2, order):
        prev = levels[-1]
        cur = sorted((e for e in all_exps if sum(e) == deg), reverse=True)
        for e in cur:
            i = next(i for i in range(3) if e[i] > 0)
            parent.append(start + prev.index(tuple(e[j] - (j == i) for j in range(3))))
            comp.append(i)
        start += len(prev)
        levels.append(cur)
    ordered = [e for lev in levels for e in lev]
    perm = [all_exps.index(e) for e in ordered]
    return ordered, np.asarray(parent, np.int64), np.asarray(comp, np.int64), coeffs[perm].T.copy()

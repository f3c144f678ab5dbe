"""Gaunt tensor vs sympy's real_gaunt (Wigner-3j based) and product matrices vs quadrature of products.

Sign conversion to sympy (also in ``prt_torch/sh/product.py``): ``sympy.physics.wigner.real_gaunt`` integrates
sympy's real SH ``Z_l^mu = sum_m U^mu_m Y_l^m`` (``U`` from its docstring, ``Y_l^m`` with the
Condon-Shortley phase). Working it out gives ``Z_l^mu = (-1)^mu y_{l,mu}`` for this project's ``y`` (no CS
phase, ``mu < 0`` -> ``sin(|mu| phi)``, flat index ``l(l+1) + mu``): the ordering agrees and the per-(l, m)
sign is ``s_lm = (-1)^m``. :func:`test_sympy_real_sh_sign_is_minus_one_to_the_m` derives this numerically
from sympy's own ``Ynm`` and ``U``; then ``real_gaunt = s1 s2 s3 Gamma``, where ``s1 s2 s3 = +1`` on every
non-zero entry (|m| sum is even by the real-SH selection rule) — asserted entry by entry below with the
signs applied explicitly, so a wrong ordering or a missing sign would fail.
"""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
import sympy as sp
import torch
from sympy.physics.wigner import real_gaunt

from prt_torch.errors import PrtError
from prt_torch.sh.basis import sh_basis, sh_index
from prt_torch.sh.product import gaunt_tensor, product_matrix, sh_product
from prt_torch.sh.quadrature import sphere_quadrature
from tests.tolerance import assert_bitwise


def _lm(order: int) -> list[tuple[int, int]]:
    return [(l, m) for l in range(order) for m in range(-l, l + 1)]


def _sympy_real_sh(l: int, mu: int, theta: float, phi: float) -> complex:
    """sympy's real SH via its real_gaunt docstring's unitary U applied to sympy's Ynm."""

    def y(m: int) -> complex:
        return complex(sp.Ynm(l, m, sp.Float(theta), sp.Float(phi)).expand(func=True).evalf())

    if mu == 0:
        return y(0)
    if mu > 0:  # U^mu_m = (delta_{m,mu} + (-1)^m delta_{m,-mu}) / sqrt2
        return (y(mu) + (-1) ** mu * y(-mu)) / math.sqrt(2)
    # mu < 0: U^mu_m = i ((-1)^m delta_{m,mu} - delta_{m,-mu}) / sqrt2
    return 1j * ((-1) ** mu * y(mu) - y(-mu)) / math.sqrt(2)


def test_sympy_real_sh_sign_is_minus_one_to_the_m() -> None:
    pts = [(0.7, 1.9), (2.1, -0.4)]
    for theta, phi in pts:
        d = np.array([[math.sin(theta) * math.cos(phi), math.sin(theta) * math.sin(phi), math.cos(theta)]])
        ours = sh_basis(d, 4)[0]
        for l, m in _lm(4):
            z = _sympy_real_sh(l, m, theta, phi)
            assert abs(z.imag) < 1e-12
            assert z.real == pytest.approx((-1) ** m * ours[sh_index(l, m)], abs=1e-12), (l, m)


def _sign(m: int) -> int:
    return -1 if m % 2 else 1


def test_gaunt_matches_sympy_real_gaunt_order4_all_entries() -> None:
    g = gaunt_tensor(4).dense()
    lm = _lm(4)
    for i, j, k in itertools.combinations_with_replacement(range(16), 3):
        (l1, m1), (l2, m2), (l3, m3) = lm[i], lm[j], lm[k]
        ref = float(real_gaunt(l1, l2, l3, m1, m2, m3))
        s = _sign(m1) * _sign(m2) * _sign(m3)
        assert s * g[i, j, k] == pytest.approx(ref, abs=1e-12), (lm[i], lm[j], lm[k])


def test_gaunt_matches_sympy_real_gaunt_order6_sample() -> None:
    g = gaunt_tensor(6).dense()
    lm = _lm(6)
    rng = np.random.default_rng(0)
    nz = np.argwhere(g != 0)
    zero = np.argwhere(g == 0)
    picks = np.concatenate(
        [nz[rng.choice(len(nz), 250, replace=False)], zero[rng.choice(len(zero), 100, replace=False)]]
    )
    band5 = [sh_index(5, m) for m in range(-5, 6)]
    picks = np.concatenate([picks, [[b, sh_index(3, 2), sh_index(2, -2)] for b in band5]])
    for i, j, k in picks:
        (l1, m1), (l2, m2), (l3, m3) = lm[i], lm[j], lm[k]
        ref = float(real_gaunt(l1, l2, l3, m1, m2, m3))
        s = _sign(m1) * _sign(m2) * _sign(m3)
        assert s * g[i, j, k] == pytest.approx(ref, abs=1e-12), (lm[i], lm[j], lm[k])


def test_gaunt_basic_properties() -> None:
    t = gaunt_tensor(8)
    g = t.dense()
    assert t.order == 8 and g.shape == (64, 64, 64) and t.values.dtype == np.float64 and t.indices.dtype == np.int64
    assert g[0, 0, 0] == pytest.approx(1 / (2 * math.sqrt(math.pi)), abs=1e-14)
    # Gamma_{0jk} = delta_jk / (2 sqrt(pi))
    np.testing.assert_allclose(g[0], np.eye(64) / (2 * math.sqrt(math.pi)), atol=1e-14)
    for p in [(1, 0, 2), (2, 1, 0), (0, 2, 1)]:
        assert_bitwise(g, g.transpose(p),
                       why='the tensor is symmetrised by construction: each value is stored once and copied')
    # COO round-trip and sparsity
    dense = np.zeros_like(g)
    dense[tuple(t.indices.T)] = t.values
    assert_bitwise(dense, g, why='COO round trip of the same values')
    assert t.nnz < 0.1 * g.size
    # cached
    assert gaunt_tensor(8) is t


def test_nonzero_entries_have_even_abs_m_sum() -> None:
    """The fact that makes sympy's (-1)^m sign cancel: |m1| + |m2| + |m3| is even wherever Gamma != 0."""
    t = gaunt_tensor(8)
    absm = np.array([abs(m) for _, m in _lm(8)])
    assert ((absm[t.indices].sum(axis=1) % 2) == 0).all()
    # ...while the bands alone allow odd |m| sums (so the check above is not vacuous)
    g = t.dense()
    i, j, k = sh_index(1, 1), sh_index(1, 0), sh_index(2, 1)  # |m| sum 2: non-zero
    assert g[i, j, k] != 0
    assert g[sh_index(1, 1), sh_index(1, 1), sh_index(2, 1)] == 0  # |m| sum 3: zero


def test_gaunt_vs_independent_lebedev_quadrature_order8() -> None:
    """Gamma was computed with a Gauss product rule; re-integrate with a Lebedev rule (different nodes)."""
    dirs, w = sphere_quadrature(21)
    y = sh_basis(dirs, 8)
    ref = np.einsum("n,ni,nj,nk->ijk", w, y, y, y, optimize=True)
    np.testing.assert_allclose(gaunt_tensor(8).dense(), ref, atol=1e-12)


def test_torch_views() -> None:
    t = gaunt_tensor(3)
    d = t.torch(torch.float32)
    assert d.dtype == torch.float32 and d.shape == (9, 9, 9)
    s = t.torch(sparse=True)
    assert s.is_sparse and s.dtype == torch.float64
    assert_bitwise(s.to_dense().numpy(), t.dense(), why='a dense view of the same values')


def _quadrature_product(a: np.ndarray, b: np.ndarray, order: int) -> np.ndarray:
    """Project a(w) b(w) onto order `order` with a rule exact for the degree-3(n-1) integrand."""
    dirs, w = sphere_quadrature(3 * (order - 1))
    y = sh_basis(dirs, order)
    fa, fb = a @ y.T, b @ y.T  # (..., N)
    return (fa * fb * w) @ y


@pytest.mark.parametrize("order", [2, 4, 6])
def test_product_vs_quadrature(order: int) -> None:
    rng = np.random.default_rng(order)
    c = order * order
    a = rng.normal(size=(3, c))
    b = rng.normal(size=(3, c))
    ref = _quadrature_product(a, b, order)
    np.testing.assert_allclose(sh_product(a, b), ref, atol=1e-12)
    m = product_matrix(a)
    assert m.shape == (3, c, c)
    np.testing.assert_allclose(np.einsum("bij,bj->bi", m, b), ref, atol=1e-12)
    np.testing.assert_allclose(m, m.transpose(0, 2, 1), atol=1e-15)
    # torch float64 / float32, broadcasting batch dims
    at = torch.tensor(a, requires_grad=True)
    pt = sh_product(at, torch.tensor(b[:1]))
    np.testing.assert_allclose(pt.detach().numpy(), _quadrature_product(a, b[:1], order), atol=1e-12)
    pt.sum().backward()
    assert at.grad is not None
    p32 = sh_product(torch.tensor(a, dtype=torch.float32), torch.tensor(b, dtype=torch.float32))
    assert p32.dtype == torch.float32
    np.testing.assert_allclose(p32.numpy(), ref, atol=1e-4)


def test_product_with_constant_is_identity() -> None:
    a = np.zeros(25)
    a[0] = math.sqrt(4 * math.pi)  # the function 1
    np.testing.assert_allclose(product_matrix(a), np.eye(25), atol=1e-14)


@pytest.mark.parametrize("order", [0, 9, 2.0])
def test_bad_order(order: object) -> None:
    with pytest.raises(PrtError, match="unsupported SH order"):
        gaunt_tensor(order)  # type: ignore[arg-type]


def test_bad_inputs() -> None:
    with pytest.raises(PrtError, match="not a square"):
        product_matrix(np.ones(10))
    with pytest.raises(PrtError, match="orders 1..8"):
        product_matrix(np.ones(81))
    with pytest.raises(PrtError, match="NaN"):
        product_matrix(np.full(9, np.nan))
    with pytest.raises(PrtError, match="equal orders"):
        sh_product(np.ones(9), np.ones(16))
    with pytest.raises(PrtError, match="both numpy or both torch"):
        sh_product(np.ones(9), torch.ones(9))
    with pytest.raises(PrtError, match="floating"):
        product_matrix(np.ones(9, dtype=np.int64))


@pytest.mark.parametrize("below", ["zero", "one"])
def test_mask_below_horizon_is_the_projection_of_the_masked_function(below: str) -> None:
    """``mask_below_horizon`` vs quadrature: a band-limited ``v`` times the order-n projection of the upper-hemisphere
    indicator ``H_n`` (``H_n v``, or ``1 - H_n (1 - v)``), evaluated on an exact rule and projected back."""
    from prt_torch.sh.basis import sh_basis
    from prt_torch.sh.product import mask_below_horizon
    from prt_torch.sh.quadrature import gauss_product_rule
    from prt_torch.sh.zonal import hemisphere_zh, zh_to_sh

    order = 4
    rng = np.random.default_rng(3)
    v = rng.normal(size=(5, order * order))
    dirs, w = gauss_product_rule(3 * (order - 1))  # exact for the triple products of order-n functions
    y = sh_basis(dirs, order)  # (N, C)
    f = v @ y.T  # (5, N)
    h_n = zh_to_sh(hemisphere_zh(order), np.array([0.0, 0.0, 1.0])) @ y.T  # H projected to order n (test_zonal)
    masked = h_n * f if below == "zero" else 1.0 - h_n * (1.0 - f)
    want = (masked * w) @ y
    np.testing.assert_allclose(mask_below_horizon(v, order, below), want, atol=1e-6 * np.abs(want).max())
    assert_bitwise(mask_below_horizon(v, order, None), v, why='no mask: the input is returned unchanged')
    with pytest.raises(PrtError, match="below_horizon"):
        mask_below_horizon(v, order, "half")

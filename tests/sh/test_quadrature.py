"""Sphere quadrature vs closed-form monomial integrals; direction sets and rotations vs their definitions."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.special import gammaln

from prt_torch.errors import PrtError
from prt_torch.sh.basis import sh_basis
from prt_torch.sh.quadrature import (
    gauss_product_rule,
    hemisphere_directions,
    random_rotations,
    rotations_about_z,
    sphere_directions,
    sphere_quadrature,
)
from tests.tolerance import assert_bitwise


def _monomial_integral(a: int, b: int, c: int) -> float:
    """Closed form of int_S2 x^a y^b z^c dw (Folland 2001): 0 unless all even, else
    2 G((a+1)/2) G((b+1)/2) G((c+1)/2) / G((a+b+c+3)/2)."""
    if a % 2 or b % 2 or c % 2:
        return 0.0
    log = gammaln((a + 1) / 2) + gammaln((b + 1) / 2) + gammaln((c + 1) / 2) - gammaln((a + b + c + 3) / 2)
    return 2 * math.exp(log)


def _monomials(degree: int, count: int, seed: int = 0) -> list[tuple[int, int, int]]:
    rng = np.random.default_rng(seed)
    out = [(0, 0, degree), (degree, 0, 0), (0, degree, 0)]
    for _ in range(count):
        a = int(rng.integers(0, degree + 1))
        b = int(rng.integers(0, degree - a + 1))
        out.append((a, b, degree - a - b))
    return out


@pytest.mark.parametrize("degree", [0, 2, 5, 10, 21, 35, 140])
def test_exact_for_monomials_up_to_degree(degree: int) -> None:
    dirs, w = sphere_quadrature(degree)
    assert dirs.dtype == np.float64 and w.dtype == np.float64 and dirs.shape == (w.shape[0], 3)
    np.testing.assert_allclose(w.sum(), 4 * math.pi, rtol=1e-13)
    assert (w > 0).all()
    np.testing.assert_allclose(np.linalg.norm(dirs, axis=1), 1.0, atol=1e-14)
    for d in {degree, max(degree - 1, 0), degree // 2}:
        for a, b, c in _monomials(d, 12):
            got = float((w * dirs[:, 0] ** a * dirs[:, 1] ** b * dirs[:, 2] ** c).sum())
            assert got == pytest.approx(_monomial_integral(a, b, c), abs=1e-12), (a, b, c)


def test_gauss_product_rule_exact_and_not_beyond() -> None:
    dirs, w = gauss_product_rule(9)
    for a, b, c in _monomials(9, 20) + _monomials(8, 20):
        got = float((w * dirs[:, 0] ** a * dirs[:, 1] ** b * dirs[:, 2] ** c).sum())
        assert got == pytest.approx(_monomial_integral(a, b, c), abs=1e-13)
    # degree 10 in z is beyond 5 Gauss nodes: the rule must be visibly inexact there
    assert abs(float((w * dirs[:, 2] ** 10).sum()) - _monomial_integral(0, 0, 10)) > 1e-6


def test_lebedev_degree3_is_not_exact_for_degree4() -> None:
    dirs, w = sphere_quadrature(3)  # the 6-point octahedron rule
    assert dirs.shape == (6, 3)
    assert abs(float((w * dirs[:, 2] ** 4).sum()) - 4 * math.pi / 5) > 0.1


@pytest.mark.parametrize("order", [1, 4, 8, 16])
def test_orthonormality_by_quadrature(order: int) -> None:
    dirs, w = sphere_quadrature(2 * (order - 1))
    y = sh_basis(dirs, order)
    gram = (y * w[:, None]).T @ y
    np.testing.assert_allclose(gram, np.eye(order * order), atol=1e-10)


def test_hemisphere_directions_uniform_and_low_discrepancy() -> None:
    n = 4096
    d = hemisphere_directions(n)
    assert d.shape == (n, 3) and d.dtype == np.float64
    assert (d[:, 2] >= 0).all()
    np.testing.assert_allclose(np.linalg.norm(d, axis=1), 1.0, atol=1e-14)
    w = 2 * math.pi / n
    # int_{z>0} z dw = pi, int z^2 = 2pi/3, int x^2 = 2pi/3, int x = 0: low discrepancy -> O(1/n)-ish errors
    assert w * d[:, 2].sum() == pytest.approx(math.pi, abs=2e-3)
    assert w * (d[:, 2] ** 2).sum() == pytest.approx(2 * math.pi / 3, abs=2e-3)
    assert w * (d[:, 0] ** 2).sum() == pytest.approx(2 * math.pi / 3, abs=2e-3)
    assert abs(w * d[:, 0].sum()) < 2e-3 and abs(w * d[:, 1].sum()) < 2e-3


def test_hemisphere_directions_seeded() -> None:
    a = hemisphere_directions(1000, seed=1)
    b = hemisphere_directions(1000, seed=1)
    c = hemisphere_directions(1000, seed=2)
    assert_bitwise(a, b, why='the same seeded generator twice')
    assert np.abs(a - c).max() > 0.1
    assert (a[:, 2] >= 0).all()
    assert 2 * math.pi / 1000 * a[:, 2].sum() == pytest.approx(math.pi, abs=1e-2)


def test_sphere_directions_moments() -> None:
    n = 3000
    d = sphere_directions(n, seed=5)
    w = 4 * math.pi / n
    np.testing.assert_allclose(w * d.sum(0), 0.0, atol=1e-2)
    np.testing.assert_allclose(w * (d**2).sum(0), 4 * math.pi / 3, atol=1e-2)


def test_random_rotations() -> None:
    r = random_rotations(20000, seed=3)
    assert r.shape == (20000, 3, 3)
    np.testing.assert_allclose(r @ r.transpose(0, 2, 1), np.broadcast_to(np.eye(3), r.shape), atol=1e-12)
    np.testing.assert_allclose(np.linalg.det(r), 1.0, atol=1e-12)
    assert_bitwise(random_rotations(3, seed=3), random_rotations(3, seed=3), why='the same seeded generator twice')
    # Haar measure: E[R] = 0 and the rotated +z axis is uniform on the sphere (E[z^2] = 1/3)
    np.testing.assert_allclose(r.mean(0), 0.0, atol=0.02)
    assert (r[:, 2, 2] ** 2).mean() == pytest.approx(1 / 3, abs=0.01)


def test_rotations_about_z() -> None:
    a = np.array([0.0, 0.3, math.pi / 2])
    r = rotations_about_z(a)
    x = r @ np.array([1.0, 0.0, 0.0])
    np.testing.assert_allclose(x, np.stack([np.cos(a), np.sin(a), 0 * a], 1), atol=1e-15)
    np.testing.assert_allclose(r @ np.array([0.0, 0.0, 1.0]), np.tile([0.0, 0.0, 1.0], (3, 1)))


@pytest.mark.parametrize("degree", [-1, 2001, 2.5, True])
def test_bad_degree(degree: object) -> None:
    with pytest.raises(PrtError, match="quadrature degree"):
        sphere_quadrature(degree)  # type: ignore[arg-type]


def test_bad_inputs() -> None:
    with pytest.raises(PrtError, match="positive integer"):
        hemisphere_directions(0)
    with pytest.raises(PrtError, match="seed"):
        hemisphere_directions(10, seed="x")  # type: ignore[arg-type]
    with pytest.raises(PrtError, match="positive integer"):
        random_rotations(-2)
    with pytest.raises(PrtError, match="shape"):
        rotations_about_z(np.zeros((2, 2)))
    with pytest.raises(PrtError, match="NaN"):
        rotations_about_z(np.array([np.nan]))

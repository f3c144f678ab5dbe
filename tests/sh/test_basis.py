"""Real SH basis vs scipy's complex SH and vs quadrature-free identities."""

from __future__ import annotations

import math

import numpy as np
import pytest
import scipy.special as sp
import torch

from prt_torch.errors import PrtError
from prt_torch.sh.basis import band_of, num_coeffs, order_from_coeffs, sh_basis, sh_index


def _random_dirs(n: int, seed: int = 0) -> np.ndarray:
    d = np.random.default_rng(seed).normal(size=(n, 3))
    return d / np.linalg.norm(d, axis=-1, keepdims=True)


def _scipy_real_sh(l: int, m: int, d: np.ndarray) -> np.ndarray:
    """This project's real SH built from scipy's complex SH (which carries the Condon-Shortley phase).

    ``y_lm = sqrt(2) (-1)^m Re Y_l^m`` (m > 0), ``sqrt(2) (-1)^m Im Y_l^|m|`` (m < 0), ``Y_l^0``:
    the ``(-1)^m`` cancels scipy's Condon-Shortley phase.
    """
    theta = np.arccos(np.clip(d[:, 2], -1, 1))
    phi = np.arctan2(d[:, 1], d[:, 0])
    c = sp.sph_harm_y(l, abs(m), theta, phi)
    if m > 0:
        return math.sqrt(2) * (-1) ** m * c.real
    if m < 0:
        return math.sqrt(2) * (-1) ** m * c.imag
    return c.real


@pytest.mark.parametrize("backend", ["numpy", "torch"])
def test_matches_scipy_up_to_order_8(backend: str) -> None:
    d = _random_dirs(2000)
    y = sh_basis(d if backend == "numpy" else torch.from_numpy(d), 8)
    y = np.asarray(y)
    for l in range(8):
        for m in range(-l, l + 1):
            np.testing.assert_allclose(y[:, sh_index(l, m)], _scipy_real_sh(l, m, d), atol=1e-12)


def test_band1_is_ramamoorthi_hanrahan() -> None:
    d = _random_dirs(10)
    y = sh_basis(d, 2)
    c = math.sqrt(3 / (4 * math.pi))  # 0.488603
    np.testing.assert_allclose(y[:, 1:4], c * d[:, [1, 2, 0]], atol=1e-14)
    np.testing.assert_allclose(y[:, 0], 0.5 / math.sqrt(math.pi), atol=1e-15)


def test_float32_and_autograd() -> None:
    d = torch.tensor(_random_dirs(50), dtype=torch.float32, requires_grad=True)
    y = sh_basis(d, 6)
    assert y.dtype == torch.float32 and y.shape == (50, 36)
    y.sum().backward()
    assert d.grad is not None and torch.isfinite(d.grad).all()


def test_index_helpers() -> None:
    assert num_coeffs(4) == 16 and order_from_coeffs(36) == 6
    assert list(band_of(3)) == [0, 1, 1, 1, 2, 2, 2, 2, 2]
    with pytest.raises(PrtError, match="not a square"):
        order_from_coeffs(10)


@pytest.mark.parametrize(
    "bad, match",
    [
        (np.zeros((4, 2)), "shape"),
        (np.full((4, 3), np.nan), "NaN"),
        (np.ones((4, 3)), "unit"),
    ],
)
def test_bad_directions(bad: np.ndarray, match: str) -> None:
    with pytest.raises(PrtError, match=match):
        sh_basis(bad, 3)


@pytest.mark.parametrize("order", [0, 17, 2.5])
def test_bad_order(order: object) -> None:
    with pytest.raises(PrtError, match="unsupported SH order"):
        sh_basis(_random_dirs(3), order)  # type: ignore[arg-type]

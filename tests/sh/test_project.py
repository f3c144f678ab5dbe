"""Projection / reconstruction vs closed-form SH coefficients and exact quadrature."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from prt_torch.errors import PrtError
from prt_torch.sh.basis import sh_basis, sh_index
from prt_torch.sh.project import evaluate, project, reconstruct
from prt_torch.sh.quadrature import sphere_quadrature


def test_z_squared_closed_form() -> None:
    """z^2 = 1/3 + 2/3 P_2(z): f_00 = (4 pi/3) / (2 sqrt(pi)), f_20 = (2/3) sqrt(5/(4 pi)) (4 pi/5)."""
    dirs, w = sphere_quadrature(6)
    c = project(dirs[:, 2] ** 2, dirs, w, 4)
    expect = np.zeros(16)
    expect[0] = 4 * math.pi / 3 / (2 * math.sqrt(math.pi))
    expect[sh_index(2, 0)] = 2 / 3 * math.sqrt(5 / (4 * math.pi)) * 4 * math.pi / 5
    np.testing.assert_allclose(c, expect, atol=1e-14)


@pytest.mark.parametrize("backend", ["numpy", "torch64", "torch32"])
def test_roundtrip_band_limited(backend: str) -> None:
    order = 6
    rng = np.random.default_rng(0)
    coeffs = rng.normal(size=(order * order, 3))
    dirs, w = sphere_quadrature(2 * (order - 1))
    values = evaluate(coeffs, dirs)  # (N, 3)
    np.testing.assert_allclose(values, sh_basis(dirs, order) @ coeffs, atol=1e-12)
    if backend == "numpy":
        got = project(values, dirs, w, order)
        tol = 1e-12
    else:
        dt = torch.float64 if backend == "torch64" else torch.float32
        got = project(torch.tensor(values, dtype=dt), torch.tensor(dirs, dtype=dt), torch.tensor(w, dtype=dt), order)
        assert got.dtype == dt
        got = got.numpy()
        tol = 1e-12 if backend == "torch64" else 2e-4
    assert got.shape == (36, 3)
    np.testing.assert_allclose(got, coeffs, atol=tol)


def test_reconstruct_layout_and_grad() -> None:
    rng = np.random.default_rng(1)
    c = rng.normal(size=(2, 5, 16))
    d = rng.normal(size=(7, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    v = reconstruct(c, d)
    assert v.shape == (2, 5, 7)
    np.testing.assert_allclose(v[1, 2], sh_basis(d, 4) @ c[1, 2], atol=1e-13)
    ct = torch.tensor(c, requires_grad=True)
    reconstruct(ct, torch.tensor(d)).sum().backward()
    assert ct.grad is not None and ct.grad.shape == ct.shape


def test_bad_inputs() -> None:
    dirs, w = sphere_quadrature(4)
    n = dirs.shape[0]
    with pytest.raises(PrtError, match="values must have shape"):
        project(np.ones(n + 1), dirs, w, 3)
    with pytest.raises(PrtError, match="weights must have shape"):
        project(np.ones(n), dirs, w[:-1], 3)
    with pytest.raises(PrtError, match="unit"):
        project(np.ones(n), dirs * 2, w, 3)
    with pytest.raises(PrtError, match="NaN"):
        project(np.full(n, np.nan), dirs, w, 3)
    with pytest.raises(PrtError, match="unsupported SH order"):
        project(np.ones(n), dirs, w, 0)
    with pytest.raises(PrtError, match="all numpy or all torch"):
        project(torch.ones(n, dtype=torch.float64), dirs, w, 3)
    with pytest.raises(PrtError, match="not a square"):
        reconstruct(np.ones(10), dirs)
    with pytest.raises(PrtError, match="shape"):
        reconstruct(np.ones(9), dirs[None])

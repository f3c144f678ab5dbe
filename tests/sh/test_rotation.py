"""SH rotation (Ivanic-Ruedenberg) vs re-projection of the rotated function and closed forms."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from prt_torch.errors import PrtError
from prt_torch.sh.basis import sh_basis, sh_index
from prt_torch.sh.project import project
from prt_torch.sh.quadrature import random_rotations, rotations_about_z, sphere_quadrature
from prt_torch.sh.rotation import sh_rotation
from prt_torch.sh.zonal import zh_to_sh


def _reprojected(R: np.ndarray, f: np.ndarray, order: int) -> np.ndarray:
    """Coefficients of g(w) = f(R^T w) by exact quadrature (degree 2(order-1))."""
    dirs, w = sphere_quadrature(2 * (order - 1))
    g_vals = sh_basis(dirs @ R, order) @ f  # row-vector form of R^T w
    return project(g_vals, dirs, w, order)


@pytest.mark.parametrize("order", [1, 2, 6, 9])
def test_matches_reprojection_random_rotations(order: int) -> None:
    rs = random_rotations(8, seed=order)
    f = np.random.default_rng(order).normal(size=order * order)
    d = sh_rotation(rs, order)
    assert d.shape == (8, order * order, order * order) and d.dtype == np.float64
    for k in range(8):
        np.testing.assert_allclose(d[k] @ f, _reprojected(rs[k], f, order), atol=1e-12)


def test_torch_matches_numpy_and_is_differentiable() -> None:
    rs = random_rotations(5, seed=0)
    d = sh_rotation(rs, 6)
    dt = sh_rotation(torch.tensor(rs), 6)
    assert dt.dtype == torch.float64
    np.testing.assert_allclose(dt.numpy(), d, atol=1e-13)
    d32 = sh_rotation(torch.tensor(rs, dtype=torch.float32), 6)
    assert d32.dtype == torch.float32
    np.testing.assert_allclose(d32.numpy(), d, atol=1e-5)
    rt = torch.tensor(rs[0], requires_grad=True)
    sh_rotation(rt, 5).sum().backward()
    assert rt.grad is not None and torch.isfinite(rt.grad).all()


def test_group_properties() -> None:
    r1, r2 = random_rotations(2, seed=11)
    d1, d2, d12 = sh_rotation(np.stack([r1, r2, r1 @ r2]), 7)
    np.testing.assert_allclose(d1 @ d2, d12, atol=1e-12)
    np.testing.assert_allclose(d1 @ d1.T, np.eye(49), atol=1e-12)
    np.testing.assert_allclose(sh_rotation(r1.T, 7), d1.T, atol=1e-12)
    np.testing.assert_allclose(sh_rotation(np.eye(3), 7), np.eye(49), atol=1e-15)


def test_band1_and_z_rotation_closed_forms() -> None:
    r = random_rotations(1, seed=4)[0]
    p = [1, 2, 0]  # band 1 is (y, z, x)
    np.testing.assert_allclose(sh_rotation(r, 2)[1:, 1:], r[np.ix_(p, p)], atol=1e-15)
    a = 0.7
    d = sh_rotation(rotations_about_z(np.array([a]))[0], 5)
    # f(phi - a): cos(m phi) -> cos(ma) cos(m phi) + sin(ma) sin(m phi); sin(m phi) -> cos(ma) sin - sin(ma) cos
    for l in range(5):
        for m in range(1, l + 1):
            ip, im = sh_index(l, m), sh_index(l, -m)
            assert d[ip, ip] == pytest.approx(math.cos(m * a), abs=1e-13)
            assert d[im, im] == pytest.approx(math.cos(m * a), abs=1e-13)
            assert d[im, ip] == pytest.approx(math.sin(m * a), abs=1e-13)
            assert d[ip, im] == pytest.approx(-math.sin(m * a), abs=1e-13)


def test_rotated_zonal_function() -> None:
    """A ZH lobe about s rotated by R is the same lobe about R s."""
    rng = np.random.default_rng(2)
    s = rng.normal(size=3)
    s /= np.linalg.norm(s)
    g = rng.normal(size=6)
    r = random_rotations(1, seed=9)[0]
    np.testing.assert_allclose(sh_rotation(r, 6) @ zh_to_sh(g, s), zh_to_sh(g, r @ s), atol=1e-12)


@pytest.mark.parametrize(
    "bad, match",
    [
        (np.eye(3) * 2, "orthonormal"),
        (np.diag([1.0, 1.0, -1.0]), "det"),
        (np.full((3, 3), np.nan), "NaN"),
        (np.eye(4), "shape"),
        (np.eye(3, dtype=np.int64), "floating"),
    ],
)
def test_bad_rotation(bad: np.ndarray, match: str) -> None:
    with pytest.raises(PrtError, match=match):
        sh_rotation(bad, 4)


def test_bad_order() -> None:
    with pytest.raises(PrtError, match="unsupported SH order"):
        sh_rotation(np.eye(3), 0)


@pytest.mark.parametrize("backend", ["numpy", "torch"])
def test_chunked_batches_and_blocks(backend: str, monkeypatch: pytest.MonkeyPatch) -> None:
    import prt_torch.sh.rotation as rot

    rs = random_rotations(14, seed=5).reshape(2, 7, 3, 3)
    x = rs if backend == "numpy" else torch.tensor(rs)
    whole = np.asarray(rot.sh_rotation(x, 5))
    monkeypatch.setattr(rot, "_CHUNK", 3)
    chunked = np.asarray(rot.sh_rotation(x, 5))
    assert chunked.shape == (2, 7, 25, 25)
    np.testing.assert_allclose(chunked, whole, atol=1e-15)
    blocks = rot.sh_rotation_blocks(x, 5)
    for l, b in enumerate(blocks):
        assert tuple(b.shape) == (2, 7, 2 * l + 1, 2 * l + 1)
        np.testing.assert_allclose(np.asarray(b), whole[..., l * l : (l + 1) ** 2, l * l : (l + 1) ** 2], atol=1e-15)
    # and against re-projection for one element
    f = np.random.default_rng(0).normal(size=25)
    np.testing.assert_allclose(whole[1, 3] @ f, _reprojected(rs[1, 3], f, 5), atol=1e-12)

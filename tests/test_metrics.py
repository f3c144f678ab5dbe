"""Metrics against quadrature and closed forms (the shipping-path shading is tested in tests/eval)."""

from __future__ import annotations

import numpy as np
import pytest

from prt_torch.errors import PrtError
from prt_torch.metrics import jitter, psnr, rel_rmse, transfer_error, vis_rel_err
from prt_torch.sh.basis import sh_basis
from prt_torch.sh.quadrature import hemisphere_directions, sphere_quadrature


def test_vis_rel_err_is_relative_integrated_error() -> None:
    """Parseval: the SH L2 error equals the integral of the squared difference over the sphere."""
    rng = np.random.default_rng(0)
    a, b = rng.normal(size=(2, 3, 16)), rng.normal(size=(2, 3, 16))
    d, w = sphere_quadrature(10)
    y = sh_basis(d, 4)
    num = ((((a - b) @ y.T) ** 2) * w).sum()
    den = (((b @ y.T) ** 2) * w).sum()
    assert vis_rel_err(a, b) == pytest.approx(np.sqrt(num / den), rel=1e-10)


def test_transfer_error_is_hemisphere_integral() -> None:
    rng = np.random.default_rng(1)
    a, b = rng.normal(size=(1, 2, 9)), rng.normal(size=(1, 2, 9))
    d = hemisphere_directions(20000)  # spherical Fibonacci, equal weights 2 pi / n
    diff = (a - b) @ sh_basis(d, 3).T  # (1, 2, N)
    ref = (diff**2).sum(-1) * 2 * np.pi / len(d)
    np.testing.assert_allclose(transfer_error(a, b), ref, rtol=1e-3)


def test_psnr_rmse_jitter_closed_forms() -> None:
    t = np.linspace(0, 2, 50).reshape(5, 10)
    p = t + 0.1
    assert psnr(p, t) == pytest.approx(10 * np.log10(4 / 0.01))
    assert rel_rmse(p, t) == pytest.approx(0.1 / np.sqrt((t**2).mean()))
    assert jitter(p, t) == pytest.approx(0.0, abs=1e-12)  # a constant offset does not jitter
    q = t.copy()
    q[::2] += 0.1  # alternating error: every frame step is off by 0.1
    assert jitter(q, t) == pytest.approx(0.1 / np.sqrt((t**2).mean()))
    with pytest.raises(PrtError, match="differ in shape"):
        psnr(t, t[:2])
    with pytest.raises(PrtError, match="NaN"):
        vis_rel_err(np.full_like(t, np.nan), t)


def _light(order: int, seed: int = 2) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return rng.normal(size=(order * order, 3)) * np.r_[1.0, [0.3] * 3, [0.1] * (order * order - 4)][:, None]


def _rot(angle: float) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]]) @ np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])

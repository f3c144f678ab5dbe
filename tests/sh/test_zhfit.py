"""ZH lobe fitting: exact recovery of synthetic lobes, eq. 15 coefficients, rotation, torch-free import."""

from __future__ import annotations

import math
import subprocess
import sys

import numpy as np
import pytest

from prt_torch.errors import PrtError
from prt_torch.sh.basis import sh_basis
from prt_torch.sh.quadrature import random_rotations
from prt_torch.sh.rotation import sh_rotation
from prt_torch.sh.zhfit import ZHLobes, fit_zh_lobes
from prt_torch.sh.zonal import clamped_cosine_zh, lobes_to_sh, zh_to_sh


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


@pytest.mark.parametrize("order", [3, 4, 6])
def test_recovers_single_rgb_lobe_exactly(order: int) -> None:
    rng = np.random.default_rng(order)
    s = _unit(rng.normal(size=3))
    g = rng.normal(size=(order, 3))
    g[0] = np.abs(g[0]) + 1
    sh = lobes_to_sh(s[None], g[None])  # (C, 3)
    lobes = fit_zh_lobes(sh, n_lobes=1)
    assert isinstance(lobes, ZHLobes) and lobes.dirs.shape == (1, 3) and lobes.coeffs.shape == (1, order, 3)
    assert lobes.rel_error < 1e-10
    np.testing.assert_allclose(lobes.to_sh(), sh, atol=1e-10)
    # the axis is s, or -s with g_l -> (-1)^l g_l (the same function)
    sign = float(np.sign(lobes.dirs[0] @ s))
    np.testing.assert_allclose(lobes.dirs[0], sign * s, atol=1e-9)
    parity = sign ** np.arange(order)
    np.testing.assert_allclose(lobes.coeffs[0], g * parity[:, None], atol=1e-9)


def test_recovers_single_mono_lobe() -> None:
    s = _unit(np.array([-0.2, 0.9, 0.3]))
    g = 5.0 * clamped_cosine_zh(5)  # a clamped-cosine "sky" lobe: odd bands vanish above l = 1
    sh = zh_to_sh(g, s)
    lobes = fit_zh_lobes(sh, n_lobes=1, n_candidates=300, seed=7)
    assert lobes.coeffs.shape == (1, 5) and lobes.to_sh().shape == (25,)
    assert lobes.rel_error < 1e-10
    assert abs(float(lobes.dirs[0] @ s)) == pytest.approx(1.0, abs=1e-12)  # +-s (with g_1 -> -g_1) are equal
    np.testing.assert_allclose(lobes.to_sh(), sh, atol=1e-9)


def test_greedy_lobe_uses_eq15_coefficients() -> None:
    """Without the joint polish the first lobe's coefficients are eq. 15 at its axis (computed here directly)."""
    rng = np.random.default_rng(5)
    sh = rng.normal(size=(16, 3))
    lobes = fit_zh_lobes(sh, n_lobes=1, joint=False)
    y = sh_basis(lobes.dirs, 4)[0]
    for l in range(4):
        sl = slice(l * l, (l + 1) ** 2)
        eq15 = (y[sl, None] * sh[sl]).sum(0) / (y[sl] ** 2).sum()
        np.testing.assert_allclose(lobes.coeffs[0, l], eq15, atol=1e-12)
    # and the axis is a local optimum: no better axis among 5000 random ones
    cand = _unit(rng.normal(size=(5000, 3)))
    yc = sh_basis(cand, 4)
    best = 0.0
    for l in range(4):
        sl = slice(l * l, (l + 1) ** 2)
        num = yc[:, sl] @ sh[sl]  # (M, 3)
        best = best + (num**2).sum(1) / ((2 * l + 1) / (4 * math.pi))
    fit_gain = float((sh**2).sum() - (lobes.rel_error**2) * (sh**2).sum())
    assert fit_gain >= best.max() - 1e-9


def test_rel_error_definition_and_monotone_in_k() -> None:
    rng = np.random.default_rng(6)
    dirs = _unit(rng.normal(size=(4, 3)))
    coeffs = np.abs(rng.normal(size=(4, 5, 3)))
    sh = lobes_to_sh(dirs, coeffs) + 0.05 * rng.normal(size=(25, 3))
    errs = []
    for k in (1, 2, 3, 4):
        lobes = fit_zh_lobes(sh, n_lobes=k)
        assert lobes.n_lobes == k and lobes.order == 5
        direct = np.linalg.norm(lobes.to_sh() - sh) / np.linalg.norm(sh)
        assert lobes.rel_error == pytest.approx(direct, rel=1e-9, abs=1e-14)
        np.testing.assert_allclose(np.linalg.norm(lobes.dirs, axis=1), 1.0, atol=1e-12)
        errs.append(lobes.rel_error)
    assert all(b <= a + 1e-12 for a, b in zip(errs, errs[1:], strict=False))
    assert errs[-1] < 0.1


def test_joint_refinement_never_worse_than_greedy() -> None:
    sh = np.random.default_rng(8).normal(size=(36, 3))
    assert fit_zh_lobes(sh, joint=True).rel_error <= fit_zh_lobes(sh, joint=False).rel_error + 1e-12


def test_rotate_matches_sh_rotation() -> None:
    rng = np.random.default_rng(9)
    sh = rng.normal(size=(16, 3))
    lobes = fit_zh_lobes(sh)
    r = random_rotations(1, seed=1)[0]
    rot = lobes.rotate(r)
    np.testing.assert_allclose(rot.to_sh(), sh_rotation(r, 4) @ lobes.to_sh(), atol=1e-12)
    with pytest.raises(PrtError, match="det"):
        lobes.rotate(np.diag([1.0, 1.0, -1.0]))


def test_zero_lighting() -> None:
    lobes = fit_zh_lobes(np.zeros((9, 3)))
    assert lobes.rel_error == 0.0 and np.all(lobes.coeffs == 0)


def test_imports_without_torch() -> None:
    """zhfit runs without torch (DESIGN: run-time path); no prt_torch.sh module imports torch at import time."""
    code = (
        "import sys, numpy as np; from prt_torch.sh.zhfit import fit_zh_lobes; "
        "import prt_torch.sh.product, prt_torch.sh.zonal, prt_torch.sh.rotation, prt_torch.sh.project; "
        "l = fit_zh_lobes(np.ones((9, 3))); l.rotate(np.eye(3)).to_sh(); "
        "prt_torch.sh.zonal.zh_to_sh(np.ones(3), np.array([0.0, 0.0, 1.0])); "
        "assert 'torch' not in sys.modules, 'torch imported'"
    )
    subprocess.run([sys.executable, "-c", code], check=True)


@pytest.mark.parametrize(
    "bad, kwargs, match",
    [
        (np.ones((10, 3)), {}, "not a square"),
        (np.full((9, 3), np.nan), {}, "NaN"),
        (np.ones((9, 3, 1)), {}, "shape"),
        (np.ones((9, 3), dtype=np.int64), {}, "floating"),
        (np.ones((9, 3)), {"n_lobes": 0}, "n_lobes"),
        (np.ones((9, 3)), {"n_candidates": 0}, "n_candidates"),
        (np.ones((289, 3)), {}, "unsupported SH order"),
    ],
)
def test_bad_inputs(bad: np.ndarray, kwargs: dict, match: str) -> None:
    with pytest.raises(PrtError, match=match):
        fit_zh_lobes(bad, **kwargs)

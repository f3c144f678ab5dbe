"""Tabulation, Kautz-McCool factorisation and SH projection vs LAPACK SVD and closed forms."""

from __future__ import annotations

import math

import numpy as np
import pytest

from prt_torch.brdf.analytic import CookTorrance, Lambert, Phong
from prt_torch.brdf.factor import factor_brdf, hemisphere_rule, project_factors, tabulate
from prt_torch.errors import PrtError
from prt_torch.sh.zonal import clamped_cosine_zh, zh_to_sh


def test_hemisphere_rule_exact_on_polynomials() -> None:
    d, w = hemisphere_rule(8, 16)
    assert w.sum() == pytest.approx(2 * math.pi, rel=1e-14)
    assert (w * d[:, 2] ** 3).sum() == pytest.approx(math.pi / 2, rel=1e-13)  # int z^3 = 2pi/4
    assert (w * d[:, 0] ** 2).sum() == pytest.approx(2 * math.pi / 3, rel=1e-13)
    assert abs((w * d[:, 0] * d[:, 1] * d[:, 2]).sum()) < 1e-13


@pytest.mark.parametrize("brdf", [Phong(exponent=8.0, kd=0.3, ks=0.7), CookTorrance(roughness=0.5, kd=0.3, ks=0.7)],
                         ids=["phong", "ggx"])
def test_truncation_is_optimal_and_error_is_reported(brdf: object) -> None:
    nt, npf, k = 10, 20, 6
    f = factor_brdf(brdf, k, nt, npf)
    d, w = hemisphere_rule(nt, npf)
    F = tabulate(brdf, d, d)
    A = np.sqrt(w)[:, None] * F * np.sqrt(w)[None, :]
    s = np.linalg.svd(A, compute_uv=False)  # LAPACK reference
    np.testing.assert_allclose(f.singular_values, s[:k], rtol=1e-6)
    assert f.rel_error == pytest.approx(math.sqrt((s[k:] ** 2).sum() / (s**2).sum()), rel=1e-5)
    # the factors reconstruct the table with exactly that weighted error (Eckart-Young optimum)
    approx = f.light.T @ f.view
    err = math.sqrt(((approx - F) ** 2 * w[:, None] * w[None, :]).sum() / (F**2 * w[:, None] * w[None, :]).sum())
    assert err == pytest.approx(f.rel_error, rel=1e-4)
    # more terms -> smaller error
    assert factor_brdf(brdf, k + 4, nt, npf, table=F).rel_error < f.rel_error


def test_lambert_is_rank_one_and_projects_to_the_clamped_cosine() -> None:
    f = factor_brdf(Lambert(), 1, 12, 24)
    assert f.rel_error < 1e-6
    u, w = project_factors(f, 5)
    # f~ = cos+(wi)/pi * 1(wo): u (x) w must equal [clamped-cosine SH / pi] (x) [sqrt(4 pi) e_0]
    ref_u = zh_to_sh(clamped_cosine_zh(5), np.array([0.0, 0.0, 1.0])) / math.pi
    ref_w = np.zeros(25)
    ref_w[0] = math.sqrt(4 * math.pi)
    np.testing.assert_allclose(np.outer(u[0], w[0]), np.outer(ref_u, ref_w), atol=1e-10)


def test_bad_arguments() -> None:
    with pytest.raises(PrtError, match="positive integer"):
        factor_brdf(Lambert(), 0)
    with pytest.raises(PrtError, match="exceeds"):
        factor_brdf(Lambert(), 100, 4, 8)
    with pytest.raises(PrtError, match="shape"):
        factor_brdf(Lambert(), 2, 4, 8, table=np.zeros((3, 3)))
    with pytest.raises(PrtError, match="BRDF"):
        tabulate(object(), np.zeros((1, 3)), np.zeros((1, 3)))
    with pytest.raises(PrtError, match="unsupported SH order"):
        project_factors(factor_brdf(Lambert(), 1, 4, 8), 0)

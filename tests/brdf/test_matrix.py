"""The SH BRDF matrix (seed 001 eq. 5) vs closed forms and an independent quadrature, and its SVD factors."""

from __future__ import annotations

import math

import numpy as np
import pytest
import scipy.linalg
from scipy.integrate import quad
from scipy.special import eval_legendre

from prt_torch.brdf.analytic import BlinnPhong, Lambert, Phong
from prt_torch.brdf.factor import tabulate
from prt_torch.errors import PrtError
from prt_torch.s001.brdf_matrix import brdf_matrix, factor
from prt_torch.sh.basis import sh_basis
from prt_torch.sh.quadrature import hemisphere_directions


def test_lambert_matrix_is_the_clamped_cosine_closed_form() -> None:
    """f~ = cos/pi: view-independent, so B = (sqrt(4 pi) e_0) (c / pi)^T with c the clamped-cosine SH (about z)."""
    B = brdf_matrix(Lambert(), 4)
    c = np.zeros(16)
    for l in range(4):  # y_l0 = sqrt((2l+1)/4pi) P_l(cos): c_l0 = 2 pi int_0^1 mu y_l0 dmu, by scipy quad
        c[l * l + l] = 2 * math.pi * quad(lambda m, l=l: m * math.sqrt((2 * l + 1) / (4 * math.pi))
                                          * eval_legendre(l, m), 0, 1)[0]
    ref = np.zeros((16, 16))
    ref[0] = math.sqrt(4 * math.pi) * c / math.pi
    np.testing.assert_allclose(B, ref, atol=1e-10)


@pytest.mark.parametrize("brdf", [Phong(exponent=6.0, kd=0.3, ks=0.6), BlinnPhong(exponent=12.0, kd=0.2, ks=0.7)],
                         ids=["phong", "blinn"])
def test_matrix_vs_independent_quadrature(brdf: object) -> None:
    """The same definition (sphere projection in wi, hemisphere least squares in wo) on a different rule:
    1500 equal-weight Fibonacci directions instead of the Gauss product rule."""
    order = 3
    B = brdf_matrix(brdf, order)
    d = hemisphere_directions(1500, seed=3)
    w = 2 * math.pi / len(d)
    Y = sh_basis(d, order)
    P = w * Y.T @ tabulate(brdf, d, d)  # (C, No)
    ref = np.linalg.lstsq(Y, P.T, rcond=None)[0]
    assert np.abs(B - ref).max() <= 0.01 * np.abs(ref).max()


def test_factor_reconstructs_and_truncates_optimally() -> None:
    B = brdf_matrix(Phong(exponent=8.0, kd=0.3, ks=0.6), 4)
    s = scipy.linalg.svdvals(B)
    H, G = factor(B, terms=16)
    np.testing.assert_allclose(H @ G.T, B, atol=1e-12)
    for k in (1, 4, 8):
        H, G = factor(B, terms=k)
        assert H.shape == G.shape == (16, k)
        assert np.linalg.norm(B - H @ G.T) == pytest.approx(math.sqrt((s[k:] ** 2).sum()), rel=1e-9, abs=1e-12)


@pytest.mark.parametrize("bad", [
    lambda: factor(np.zeros((3, 4))),
    lambda: factor(np.eye(4), terms=5),
    lambda: factor(np.eye(4), terms=0),
    lambda: factor(np.full((4, 4), np.nan)),
    lambda: brdf_matrix(Lambert(), 0),
    lambda: brdf_matrix(Lambert(), 4, n_theta=2, n_phi=4),
    lambda: brdf_matrix("lambert", 2),
])
def test_bad_inputs_are_one_line_errors(bad) -> None:
    with pytest.raises(PrtError) as e:
        bad()
    assert "\n" not in str(e.value)

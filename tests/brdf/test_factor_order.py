"""Factorisation order ("before" / "after" the SH projection) against references that use no SVD.

* full rank reproduces the untruncated order-n operator: a closed form (Lambert: clamped cosine x constant) and a
  quadrature reference written here (the light lobe projected over the sphere, the view fitted by the normal
  equations over the hemisphere: numpy's pinv, not the module's lstsq / QR);
* error decreases with k (each order in its own norm, where it is a theorem; "before" also in the SH-domain norm);
* "after" is never worse than "before" in the SH-domain norm at equal k (Eckart-Young: it is the optimum there).
"""

from __future__ import annotations

import math
import warnings
from pathlib import Path

import numpy as np
import pytest

from prt_torch.brdf.analytic import Lambert
from prt_torch.brdf.factor import FACTOR_ORDERS, factor_sh, hemisphere_rule, tabulate, view_metric
from prt_torch.brdf.rpo import CATALOGUE, RPO, build_rpo, builtin_brdf, builtin_rpo, rpo_key_text
from prt_torch.errors import PrtError, PrtWarning
from prt_torch.sh.basis import sh_basis
from prt_torch.sh.zonal import clamped_cosine_zh, zh_to_sh
from tests.tolerance import assert_bitwise

NT, NP = 8, 16  # a small rule: N = 128 directions, so that "before" can run at full rank (k = N)
ORDER = 4
C = ORDER * ORDER


def reference_operator(brdf: object, nt: int = NT, npf: int = NP, order: int = ORDER) -> tuple[np.ndarray, ...]:
    """``(T (C, C), G (C, C))``: the untruncated operator by quadrature and the view SH's hemisphere Gram matrix."""
    d, w = hemisphere_rule(nt, npf)
    F = tabulate(brdf, d, d)
    y = sh_basis(d, order)
    light = np.einsum("i,ij,ic->jc", w, F, y)  # (No, C_i): per view direction, the lobe's SH over the sphere
    gram = y.T @ (w[:, None] * y)  # normal equations of the hemisphere fit in y(wo)
    return np.linalg.pinv(gram) @ (y.T @ (w[:, None] * light)), gram


def sh_norm_error(T: np.ndarray, gram: np.ndarray, u: np.ndarray, w: np.ndarray) -> float:
    """``||E||`` with ``||E||^2 = tr(E^T G E)`` (view over the hemisphere, light in SH), relative to ``||T||``."""
    e = T - w.T @ u
    return math.sqrt(np.trace(e.T @ gram @ e) / np.trace(T.T @ gram @ T))


def test_metric_is_the_gram_factor() -> None:
    d, w = hemisphere_rule(NT, NP)
    R = view_metric(d, w, ORDER)
    _, gram = reference_operator(Lambert())
    np.testing.assert_allclose(R.T @ R, gram, atol=1e-12 * np.abs(gram).max())
    assert np.allclose(R, np.triu(R)) and (np.diag(R) > 0).all()


@pytest.mark.parametrize("factor_order", FACTOR_ORDERS)
def test_full_rank_is_the_closed_form_for_lambert(factor_order: str) -> None:
    k = NT * NP if factor_order == "before" else C
    sf = factor_sh(Lambert(), ORDER, k, factor_order, NT, NP)
    # f~ = cos+(wi) / pi x 1(wo): T = sqrt(4 pi) e_0 (x) clamped-cosine SH / pi (the Gauss rule integrates the
    # clamped cosine times y_lm, degree <= 4 in z on the hemisphere, exactly)
    ref = np.outer(np.eye(C)[0] * math.sqrt(4 * math.pi), zh_to_sh(clamped_cosine_zh(ORDER), np.array([0, 0, 1.0]))
                   / math.pi)
    np.testing.assert_allclose(sf.w.T @ sf.u, ref, atol=1e-10)
    assert sf.operator_error < 1e-10


@pytest.mark.parametrize("name", ["phong", "blinn", "ggx", "ward"])
@pytest.mark.parametrize("factor_order", FACTOR_ORDERS)
def test_full_rank_reproduces_the_untruncated_operator(name: str, factor_order: str) -> None:
    brdf = builtin_brdf(name)
    T, gram = reference_operator(brdf)
    k = NT * NP if factor_order == "before" else C
    sf = factor_sh(brdf, ORDER, k, factor_order, NT, NP)
    # float64 round-off of an SVD of a 128 x 128 (or 16 x 16) table and a 16-column fit: ~1e-12 relative
    np.testing.assert_allclose(sf.w.T @ sf.u, T, atol=1e-9 * np.abs(T).max())
    assert sf.operator_error < 1e-9
    assert sh_norm_error(T, gram, sf.u, sf.w) < 1e-9


@pytest.mark.parametrize("name", ["phong", "blinn", "ggx", "ward"])
def test_error_decreases_with_k_and_after_is_never_worse(name: str) -> None:
    brdf = builtin_brdf(name)
    T, gram = reference_operator(brdf)
    d, w = hemisphere_rule(NT, NP)
    F = tabulate(brdf, d, d)
    ks = list(range(1, C + 1))
    err = {fo: [] for fo in FACTOR_ORDERS}
    own = {fo: [] for fo in FACTOR_ORDERS}
    for k in ks:
        for fo in FACTOR_ORDERS:
            sf = factor_sh(brdf, ORDER, k, fo, NT, NP, table=F)
            err[fo].append(sh_norm_error(T, gram, sf.u, sf.w))
            own[fo].append(sf.rel_error)
            # the module's own figure is this independent one
            assert sf.operator_error == pytest.approx(err[fo][-1], rel=1e-6, abs=1e-12)
    after, before = np.array(err["after"]), np.array(err["before"])
    # "after" at k is the optimum in this norm (Eckart-Young): never above "before", exact at k = C
    assert (after <= before * (1 + 1e-9) + 1e-12).all(), (after, before)
    assert after[-1] < 1e-10 and (after[:-1] > 0).all()
    # each order's truncation error in its own norm decreases strictly (a theorem, while singular values are > 0)
    for fo in FACTOR_ORDERS:
        e = np.array(own[fo])
        assert (np.diff(e[e > 1e-10]) < 0).all(), (fo, e)
    assert (np.diff(after) < 0).all()
    # "before" in the SH-domain norm: not a theorem (the projection mixes terms) but holds on the catalogue
    assert (np.diff(before) <= 1e-9).all(), before


def test_after_beyond_rank_pads_zero_terms_with_a_warning() -> None:
    brdf = builtin_brdf("phong")
    with pytest.warns(PrtWarning, match="exceed the rank 16"):
        sf = factor_sh(brdf, ORDER, 20, "after", NT, NP)
    exact = factor_sh(brdf, ORDER, C, "after", NT, NP)
    assert sf.u.shape == (20, C) and not sf.u[C:].any() and not sf.w[C:].any()
    np.testing.assert_allclose(sf.w.T @ sf.u, exact.w.T @ exact.u, atol=1e-14)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        factor_sh(brdf, ORDER, 20, "after", NT, NP, quiet=True)


def test_rpo_records_and_keys_its_factor_order(tmp_path: Path) -> None:
    brdf = builtin_brdf("blinn")
    a = build_rpo(brdf, 3, 4, NT, NP, factor_order="after")
    b = build_rpo(brdf, 3, 4, NT, NP, factor_order="before")
    assert a.factor_order == "after" and b.factor_order == "before"
    assert a.meta["operator_error"] <= b.meta["operator_error"]
    a.save(tmp_path / "a.npz")
    back = RPO.load(tmp_path / "a.npz")
    assert back.factor_order == "after"
    assert_bitwise(back.u, a.u, why="a float32 save/load round trip")
    # a file written before the option existed (no factor_order entry) is a "before" RPO
    with np.load(tmp_path / "a.npz") as z:
        old = {k: z[k] for k in z.files if k != "factor_order"}
    np.savez(tmp_path / "old.npz", **old)
    assert RPO.load(tmp_path / "old.npz").factor_order == "before"
    # cache keys: "before" keeps the old text, "after" differs; the catalogue cache honours the option
    assert rpo_key_text(brdf, 4, 8, "before") != rpo_key_text(brdf, 4, 8, "after")
    assert not rpo_key_text(brdf, 4, 8, "before").endswith("before")
    r1 = builtin_rpo("blinn", 2, 3, cache_dir=tmp_path, factor_order="after")
    r2 = builtin_rpo("blinn", 2, 3, cache_dir=tmp_path, factor_order="before")
    assert (r1.factor_order, r2.factor_order) == ("after", "before")
    assert len(list(tmp_path.glob("blinn_n2_k3_*.npz"))) == 2


def test_bad_factor_order() -> None:
    with pytest.raises(PrtError, match="unknown BRDF factorisation order 'sideways'"):
        factor_sh(Lambert(), 2, 2, "sideways", 4, 8)
    with pytest.raises(PrtError, match="unknown BRDF factorisation order"):
        build_rpo(Lambert(), 2, 2, 4, 8, factor_order="x")
    with pytest.raises(PrtError, match="unknown BRDF factorisation order"):
        RPO.from_factors(np.zeros((1, 4)), np.zeros((1, 4)), np.ones(3), "x", 0.0, factor_order="")
    assert set(CATALOGUE) >= {"phong", "blinn", "ggx", "ward", "lambert"}

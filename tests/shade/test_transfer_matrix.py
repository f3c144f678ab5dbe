"""Eq. 5 shading of transfer matrices vs exact quadrature and the project's RPO shading (unoccluded vertex)."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from prt_torch.brdf.analytic import BlinnPhong, Lambert
from prt_torch.brdf.factor import hemisphere_rule, tabulate
from prt_torch.brdf.rpo import build_rpo
from prt_torch.errors import PrtError
from prt_torch.s001.brdf_matrix import brdf_matrix, factor
from prt_torch.s001.shading import shade_matrix
from prt_torch.sh.basis import sh_basis
from prt_torch.sh.quadrature import hemisphere_directions, random_rotations
from prt_torch.sh.rotation import sh_rotation
from prt_torch.sh.zonal import hemisphere_zh, zh_to_sh
from prt_torch.shade.rpo_shading import shade_rpo

N = 4


@pytest.fixture(scope="module")
def scene():
    """One unoccluded vertex ("zero": upper hemisphere), 24 view directions, random RGB lighting."""
    F = random_rotations(1, seed=5)
    u, w = hemisphere_rule(24, 48)
    T = (sh_basis(u, N) * w[:, None]).T @ sh_basis(u @ F[0], N)  # int_H y_i(F w) y_j(w) dw, by quadrature
    L = np.random.default_rng(0).normal(size=(N * N, 3))
    L[0] += 4.0
    wo = hemisphere_directions(24, seed=3)  # local
    n = len(wo)
    return dict(F=F, T=np.repeat(T[None], n, 0), L=L, wo=wo, frames=np.repeat(F, n, 0), view=wo @ F[0], u=u, w=w)


def _exact(brdf, s):
    """int_H f~(wi, wo) L(F^T wi) dwi by the hemisphere product rule: (V, 3)."""
    Lw = sh_basis(s["u"] @ s["F"][0], N) @ s["L"]
    return tabulate(brdf, s["u"], s["wo"]).T @ (s["w"][:, None] * Lw)


def _rpo(brdf, s):
    rpo = build_rpo(brdf, order=N, k=8)
    n = len(s["wo"])
    v = torch.tensor(zh_to_sh(hemisphere_zh(N), np.array([0, 0, 1.0]))).expand(n, N * N)
    l_local = torch.tensor(sh_rotation(s["F"][0], N) @ s["L"]).expand(n, N * N, 3)
    return (shade_rpo(v, l_local, torch.tensor(s["wo"]), rpo) / torch.tensor(rpo.tint, dtype=v.dtype)).numpy()


def test_lambert_matches_exact_and_rpo(scene):
    brdf = Lambert()
    H, G = factor(brdf_matrix(brdf, N), 4)
    got = shade_matrix(scene["T"], scene["L"], scene["frames"], scene["view"], H, G)
    ex = _exact(brdf, scene)
    scale = np.abs(ex).mean()
    assert np.abs(got - ex).max() <= 0.03 * scale  # order-4 truncation of the clamped cosine
    assert np.abs(got - _rpo(brdf, scene)).max() <= 0.03 * scale


def test_glossy_matches_rpo_to_truncation_and_svd_bound(scene):
    brdf = BlinnPhong(exponent=16.0, kd=0.2, ks=0.6)
    B = brdf_matrix(brdf, N)
    full = shade_matrix(scene["T"], scene["L"], scene["frames"], scene["view"], B, np.eye(N * N))
    ex = _exact(brdf, scene)
    rpo = _rpo(brdf, scene)
    scale = np.abs(ex).mean()
    err_m, err_r = np.abs(full - ex).max(), np.abs(rpo - ex).max()
    assert err_m <= 0.25 * scale and err_r <= 0.25 * scale  # both: order-4 truncation of a glossy lobe
    assert np.abs(full - rpo).max() <= 0.1 * scale  # the two truncations agree better than either with exact
    # the 4-term factorisation moves each value by at most |y(wo)| s_5 |T L| (Eckart-Young, spectral norm)
    H, G = factor(B, 4)
    four = shade_matrix(scene["T"], scene["L"], scene["frames"], scene["view"], H, G)
    s5 = np.linalg.svd(B, compute_uv=False)[4]
    bound = np.linalg.norm(sh_basis(scene["wo"], N), axis=1)[:, None] * s5 * np.linalg.norm(
        scene["T"] @ scene["L"], axis=1)
    assert (np.abs(four - full) <= bound + 1e-9).all()
    assert np.abs(four - full).max() > 1e-3  # truncation is visible at 4 terms


def test_torch_and_numpy_agree_and_tint(scene):
    H, G = factor(brdf_matrix(Lambert(), N), 4)
    a = shade_matrix(scene["T"], scene["L"], scene["frames"], scene["view"], H, G, tint=[1.0, 0.5, 0.25])
    t = shade_matrix(torch.tensor(scene["T"]), torch.tensor(scene["L"]), torch.tensor(scene["frames"]),
                     torch.tensor(scene["view"]), torch.tensor(H), torch.tensor(G), tint=torch.tensor([1.0, 0.5, 0.25]))
    assert isinstance(t, torch.Tensor) and t.shape == (len(scene["wo"]), 3)
    np.testing.assert_allclose(t.numpy(), a, rtol=1e-10, atol=1e-12)
    b = shade_matrix(scene["T"], scene["L"], scene["frames"], scene["view"], H, G)
    np.testing.assert_allclose(a, b * np.array([1.0, 0.5, 0.25]), rtol=1e-12)


def test_bad_inputs_are_one_line_errors(scene):
    s = scene
    H, G = np.zeros((16, 4)), np.zeros((16, 4))
    cases = [
        lambda: shade_matrix(s["T"][:, :, :9], s["L"], s["frames"], s["view"], H, G),
        lambda: shade_matrix(s["T"], s["L"][:9], s["frames"], s["view"], H, G),
        lambda: shade_matrix(s["T"], s["L"], s["frames"][:3], s["view"], H, G),
        lambda: shade_matrix(s["T"], s["L"], s["frames"], s["view"] * 2, H, G),
        lambda: shade_matrix(s["T"], s["L"], s["frames"], s["view"], H[:, :3], G),
        lambda: shade_matrix(s["T"] * np.nan, s["L"], s["frames"], s["view"], H, G),
        lambda: shade_matrix([[1.0]], s["L"], s["frames"], s["view"], H, G),
    ]
    for case in cases:
        with pytest.raises(PrtError) as e:
            case()
        assert "\n" not in str(e.value)

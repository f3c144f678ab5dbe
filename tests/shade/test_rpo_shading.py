"""RPO shading (seed 003 eq. 11) vs brute-force quadrature of the shading integral, closed forms,
onnxruntime; the three evaluation orders; swapping BRDFs."""

from __future__ import annotations

import functools
import io
import math

import numpy as np
import pytest
import torch

from prt_torch.brdf.analytic import BRDF, CookTorrance, Lambert, Phong
from prt_torch.brdf.factor import hemisphere_rule
from prt_torch.brdf.rpo import RPO, build_rpo
from prt_torch.errors import PrtError
from prt_torch.sh.basis import sh_basis
from prt_torch.sh.quadrature import sphere_quadrature
from prt_torch.sh.zonal import hemisphere_zh, zh_to_sh
from prt_torch.shade.rpo_shading import METHODS, RPOShader, RPOTensors, shade_rpo

ORDER = 4
C = ORDER * ORDER


@functools.cache
def _rpo(name: str) -> tuple[BRDF, RPO]:
    brdf = {"phong": Phong(exponent=16.0, kd=0.3, ks=0.7, tint=[1.0, 0.8, 0.6]),
            "ggx": CookTorrance(roughness=0.5, f0=0.04, kd=0.5, ks=0.5, tint=[0.7, 0.9, 1.0]),
            "lambert": Lambert(tint=[0.5, 0.6, 0.7])}[name]
    return brdf, build_rpo(brdf, order=ORDER, k=8, n_theta=16, n_phi=32)


def _views(n: int, seed: int) -> np.ndarray:
    d = np.random.default_rng(seed).normal(size=(n, 3))
    d[:, 2] = np.abs(d[:, 2]) + 0.3
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def _shade64(rpo: RPO, v: np.ndarray, l: np.ndarray, wo: np.ndarray, method: str = "fused") -> np.ndarray:
    t = RPOTensors.from_rpo(rpo, torch.float64)
    V = len(wo)
    out = shade_rpo(torch.from_numpy(np.broadcast_to(v, (V, C)).copy()),
                    torch.from_numpy(np.broadcast_to(l, (V, C, 3)).copy()), torch.from_numpy(wo), t, method)
    return out.numpy()


@pytest.mark.parametrize("name", ["phong", "ggx"])
def test_matches_the_rpo_own_separable_integral(name: str) -> None:
    """Exact check of eq. 11's algebra: RPO shading == int L V sum_b (u_b.y(w)) (w_b.y(wo)) dw (quadrature)."""
    _, rpo = _rpo(name)
    rng = np.random.default_rng(1)
    l, v, wo = rng.normal(size=(C, 3)), rng.normal(size=C), _views(6, 2)
    d, w = sphere_quadrature(3 * (ORDER - 1))
    y = sh_basis(d, ORDER)
    u, wv = rpo.u.astype(np.float64), rpo.w.astype(np.float64)
    integrand = (y @ l) * (y @ v)[:, None]  # (N, 3)
    t_b = np.einsum("nb,n,nc->bc", y @ u.T, w, integrand)  # (k, 3)
    ref = np.einsum("vb,bc->vc", sh_basis(wo, ORDER) @ wv.T, t_b) * rpo.tint
    for method in METHODS:
        np.testing.assert_allclose(_shade64(rpo, v, l, wo, method), ref, atol=1e-5 * np.abs(ref).max())


@pytest.mark.parametrize("name", ["phong", "ggx"])
def test_brute_force_within_truncation_bound(name: str) -> None:
    """RPO shading vs the true integral int L V f~(w, wo) dw of band-limited L, V with the true BRDF.

    The difference comes only from the k-term factorisation and the SH truncation of the factors, so by
    Cauchy-Schwarz |err_c| <= tint_c ||L_c V||_2 ||f~(., wo) - f~_kn(., wo)||_2 (norms over the sphere).
    """
    brdf, rpo = _rpo(name)
    rng = np.random.default_rng(7)
    l = rng.normal(size=(C, 3))
    l[0] += 6.0  # mostly positive radiance
    v = zh_to_sh(hemisphere_zh(ORDER), np.array([0.0, 0.0, 1.0])) + 0.3 * rng.normal(size=C)
    wo = _views(8, 3)
    got = _shade64(rpo, v, l, wo)

    dh, wh = hemisphere_rule(96, 192)  # fine rule on the upper hemisphere (f~ = 0 below)
    yh = sh_basis(dh, ORDER)
    dl = dh * np.array([1.0, 1.0, -1.0])  # mirrored rule for the lower hemisphere
    yl = sh_basis(dl, ORDER)
    LV_up = (yh @ l) * (yh @ v)[:, None]  # (N, 3)
    dq, wq = sphere_quadrature(4 * (ORDER - 1))  # exact for (L V)^2
    yq = sh_basis(dq, ORDER)
    norm_lv = np.sqrt((((yq @ l) * (yq @ v)[:, None]) ** 2 * wq[:, None]).sum(0))  # (3,)
    u, wv = rpo.u.astype(np.float64), rpo.w.astype(np.float64)
    worst, rel = 0.0, 0.0
    for j, o in enumerate(wo):
        f_true = brdf.cosine_weighted(dh, np.broadcast_to(o, dh.shape).copy())  # (N,)
        truth = (LV_up * (f_true * wh)[:, None]).sum(0) * brdf.tint
        wb = sh_basis(o, ORDER) @ wv.T  # (k,)
        fk_up = (yh @ u.T) @ wb
        fk_lo = (yl @ u.T) @ wb
        dist = math.sqrt(((f_true - fk_up) ** 2 * wh).sum() + (fk_lo**2 * wh).sum())
        bound = brdf.tint * norm_lv * dist
        err = np.abs(got[j] - truth)
        assert (err <= bound + 1e-9).all(), (name, j, err, bound)
        worst = max(worst, float((err / bound).max()))
        rel = max(rel, float(np.abs(err).max() / np.abs(truth).max()))
        # the bound is informative: well below the size of the signal bound itself
        f_norm = math.sqrt((f_true**2 * wh).sum())
        assert dist < 0.9 * f_norm
    print(f"\n{name}: max |err| / Cauchy-Schwarz bound = {worst:.3f}; max |err| / |truth| = {rel:.3f}")


def test_unshadowed_lambert_uniform_irradiance_is_pi() -> None:
    brdf, rpo = _rpo("lambert")
    v = zh_to_sh(hemisphere_zh(ORDER), np.array([0.0, 0.0, 1.0]))  # unoccluded: upper-hemisphere indicator
    l = np.zeros((C, 3))
    l[0] = math.sqrt(4 * math.pi)  # uniform unit radiance
    out = _shade64(rpo, v, l, _views(5, 0))
    # Lambert radiance = albedo * E / pi with irradiance E = pi
    np.testing.assert_allclose(out / brdf.tint * math.pi, math.pi, rtol=1e-5)


def test_float32_module_swap_and_batch() -> None:
    _, a = _rpo("phong")
    _, b = _rpo("ggx")
    rng = np.random.default_rng(3)
    v = torch.from_numpy(rng.normal(size=(2, 5, C))).float()
    l = torch.from_numpy(rng.normal(size=(2, 5, C, 3))).float()
    wo = torch.from_numpy(_views(10, 4).reshape(2, 5, 3)).float()
    shader = RPOShader(a)
    out_a = shader(v, l, wo)
    assert out_a.shape == (2, 5, 3) and out_a.dtype == torch.float32
    wo64 = torch.nn.functional.normalize(wo.double(), dim=-1)
    ref_a = shade_rpo(v.double(), l.double(), wo64, RPOTensors.from_rpo(a, torch.float64))
    np.testing.assert_allclose(out_a.numpy(), ref_a.numpy(), atol=1e-4 * ref_a.abs().max().item())
    v0, l0, wo0 = v.clone(), l.clone(), wo.clone()
    shader.set_rpo(b)  # swapping the BRDF changes only the RPO buffers
    out_b = shader(v, l, wo)
    assert torch.equal(v, v0) and torch.equal(l, l0) and torch.equal(wo, wo0)
    np.testing.assert_allclose(out_b.numpy(), RPOShader(b)(v, l, wo).numpy(), rtol=1e-6, atol=1e-7)
    assert not torch.allclose(out_a, out_b)
    with pytest.raises(PrtError, match="same"):
        shader.set_rpo(build_rpo(Lambert(), order=3, k=8, n_theta=6, n_phi=12))


def test_onnx_export_matches_torch() -> None:
    ort = pytest.importorskip("onnxruntime")
    _, rpo = _rpo("ggx")
    rng = np.random.default_rng(5)
    for method in METHODS:
        shader = RPOShader(rpo, method)
        args = (torch.randn(3, C), torch.randn(3, C, 3), torch.from_numpy(_views(3, 1)).float())
        f = io.BytesIO()
        torch.onnx.export(shader, args, f, input_names=["v", "l", "wo"], output_names=["L"],
                          dynamic_axes={"v": {0: "V"}, "l": {0: "V"}, "wo": {0: "V"}}, dynamo=False)
        sess = ort.InferenceSession(f.getvalue(), providers=["CPUExecutionProvider"])
        v = rng.normal(size=(9, C)).astype(np.float32)
        l = rng.normal(size=(9, C, 3)).astype(np.float32)
        wo = _views(9, 8).astype(np.float32)
        got = sess.run(None, {"v": v, "l": l, "wo": wo})[0]
        ref = shader(torch.from_numpy(v), torch.from_numpy(l), torch.from_numpy(wo)).detach().numpy()
        np.testing.assert_allclose(got, ref, atol=1e-5 * np.abs(ref).max())


def test_bad_inputs() -> None:
    _, rpo = _rpo("lambert")
    t = RPOTensors.from_rpo(rpo)
    v, l, wo = torch.zeros(4, C), torch.zeros(4, C, 3), torch.tensor([[0.0, 0.0, 1.0]] * 4)
    with pytest.raises(PrtError, match="visibility must have shape"):
        shade_rpo(torch.zeros(4, 9), l, wo, t)
    with pytest.raises(PrtError, match="lighting must have shape"):
        shade_rpo(v, torch.zeros(4, C, 2), wo, t)
    with pytest.raises(PrtError, match="view directions must have shape"):
        shade_rpo(v, l, wo[:3], t)
    with pytest.raises(PrtError, match="unit"):
        shade_rpo(v, l, wo * 2, t)
    with pytest.raises(PrtError, match="NaN"):
        shade_rpo(v * float("nan"), l, wo, t)
    with pytest.raises(PrtError, match="unknown RPO evaluation method"):
        shade_rpo(v, l, wo, t, method="sparse")  # type: ignore[arg-type]
    with pytest.raises(PrtError, match="torch tensor"):
        shade_rpo(np.zeros((4, C)), l, wo, t)  # type: ignore[arg-type]

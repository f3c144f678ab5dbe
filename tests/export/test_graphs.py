"""The shading graph against an independent float64 reference (quadrature-projected lighting), and
onnxruntime against torch."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from prt_torch.export.graphs import SHADING_INPUTS, ShadingGraph, SHPolynomial
from prt_torch.export.onnx_file import export_onnx
from prt_torch.export.parity import check_parity
from prt_torch.sh.basis import band_of, sh_basis
from prt_torch.sh.polynomial import sh_polynomial


def _unit(x: np.ndarray) -> np.ndarray:
    return x / np.linalg.norm(x, axis=-1, keepdims=True)


def _rotations(rng: np.random.Generator, shape: tuple[int, ...]) -> np.ndarray:
    q, r = np.linalg.qr(rng.normal(size=shape + (3, 3)))
    q = q * np.sign(np.diagonal(r, axis1=-2, axis2=-1))[..., None, :]
    det = np.linalg.det(q)
    q[..., :, 2] *= det[..., None]  # det +1: right-handed frames
    return q


def _gauss_sphere(n: int) -> tuple[np.ndarray, np.ndarray]:
    """Product rule (Gauss-Legendre in z x uniform phi), exact for polynomials of degree < 2n."""
    z, wz = np.polynomial.legendre.leggauss(n)
    phi = np.arange(2 * n) * np.pi / n
    zz, pp = np.meshgrid(z, phi, indexing="ij")
    s = np.sqrt(1 - zz**2)
    dirs = np.stack([s * np.cos(pp), s * np.sin(pp), zz], -1).reshape(-1, 3)
    w = (wz[:, None] * np.full(2 * n, np.pi / n)[None, :]).reshape(-1)
    return dirs, w


def reference_shading(inp: dict[str, np.ndarray], order: int) -> np.ndarray:
    """Seed 003 eq. 11, float64, with the local lighting obtained by projecting the rotated world
    lighting onto the SH basis by quadrature (no SH rotation formula involved)."""
    vis = inp["visibility"]
    b, _, v = inp["frames"].shape
    frames = inp["frames"].transpose(0, 2, 1).reshape(b, v, 3, 3)  # vertex-last -> (B, V, 3, 3)
    view = inp["view_dirs"].transpose(0, 2, 1)
    s, g = inp["lobe_dirs"].astype(np.float64), inp["lobe_coeffs"].astype(np.float64)
    M, w, tint = (inp[k].astype(np.float64) for k in ("rpo_M", "rpo_w", "rpo_tint"))
    world_sh = np.einsum("kc,kcr->cr", sh_basis(_unit(s), order), g[:, band_of(order), :])  # (C, 3)
    q_dirs, q_w = _gauss_sphere(2 * order)
    y_q = sh_basis(q_dirs, order)  # (Q, C)
    world_dirs = np.einsum("bvji,qj->bvqi", frames.astype(np.float64), q_dirs)  # F^T q: local q -> world
    f_world = np.einsum("bvqc,cr->bvqr", sh_basis(world_dirs, order, check=False), world_sh)
    l_local = np.einsum("bvqr,qc,q->bvcr", f_world, y_q, q_w)
    wo = np.einsum("bvij,bvj->bvi", frames.astype(np.float64), view.astype(np.float64))
    a = sh_basis(wo, order, check=False) @ w.T  # (B, V, k)
    mv = np.einsum("kij,bvj->bvki", M, vis.astype(np.float64))
    return np.einsum("bvk,bvki,bvir->bvr", a, mv, l_local) * tint


def random_inputs(rng: np.random.Generator, b: int, v: int, order: int, k: int, n_lobes: int = 3) -> dict:
    c = order * order
    return {
        "visibility": rng.normal(size=(b, v, c)).astype(np.float32),
        "frames": np.ascontiguousarray(_rotations(rng, (b, v)).reshape(b, v, 9).transpose(0, 2, 1), np.float32),
        "view_dirs": np.ascontiguousarray(_unit(rng.normal(size=(b, v, 3))).transpose(0, 2, 1), np.float32),
        "lobe_dirs": _unit(rng.normal(size=(n_lobes, 3))).astype(np.float32),
        "lobe_coeffs": rng.normal(size=(n_lobes, order, 3)).astype(np.float32),
        "rpo_M": rng.normal(size=(k, c, c)).astype(np.float32),
        "rpo_w": rng.normal(size=(k, c)).astype(np.float32),
        "rpo_tint": rng.uniform(0.2, 1.0, size=3).astype(np.float32),
    }


@pytest.mark.parametrize("order", [1, 2, 4, 5])
def test_sh_polynomial_matches_basis(order: int) -> None:
    rng = np.random.default_rng(order)
    d = _unit(rng.normal(size=(50, 3)))
    exps, coeffs = sh_polynomial(order)
    mono = np.prod(d[:, None, :] ** exps[None], axis=-1)
    np.testing.assert_allclose(mono @ coeffs, sh_basis(d, order), atol=1e-12)
    y = SHPolynomial(order)(torch.from_numpy(d.T.copy()).float()).numpy().T
    np.testing.assert_allclose(y, sh_basis(d, order), atol=2e-6)


@pytest.mark.parametrize("order", [1, 2, 3, 4, 6])
def test_sh_polynomial_monomials_are_the_listed_powers(order: int) -> None:
    """The degree-by-degree gathered monomials equal x^a y^b z^c computed directly, for every listed
    exponent, each exponent of degree < order exactly once (non-unit points: no x^2+y^2+z^2=1 shortcut)."""
    d = np.random.default_rng(order).uniform(-1.5, 1.5, size=(40, 3))
    m = SHPolynomial(order)
    exps = np.array(m.exps)
    assert len({tuple(e) for e in m.exps}) == len(m.exps) == order * (order + 1) * (order + 2) // 6
    assert exps.sum(axis=1).max() == order - 1
    got = m.monomials(torch.from_numpy(d.T.copy())).numpy().T
    np.testing.assert_allclose(got, np.prod(d[:, None, :] ** exps[None], axis=-1), rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("order,k", [(4, 8), (3, 2)])
def test_shading_graph_matches_quadrature_reference(order: int, k: int) -> None:
    rng = np.random.default_rng(7)
    inp = random_inputs(rng, 2, 9, order, k)
    got = ShadingGraph(order, k)(*[torch.from_numpy(inp[n]) for n in SHADING_INPUTS]).numpy()
    want = reference_shading(inp, order)
    assert got.shape == (2, 9, 3)  # (B, V, 3)
    assert np.abs(got - want).max() <= 1e-4 * np.abs(want).max()


def test_shading_is_invariant_under_a_global_rotation() -> None:
    """Rotating frames, view and lobes together by one rotation leaves the radiance unchanged."""
    rng = np.random.default_rng(3)
    inp = random_inputs(rng, 1, 12, 4, 8)
    R = _rotations(rng, ()).astype(np.float32)
    b, _, v = inp["frames"].shape
    fr = inp["frames"].transpose(0, 2, 1).reshape(b, v, 3, 3) @ R.T  # F' = F R^T: local coords unchanged
    rot = dict(inp, frames=fr.reshape(b, v, 9).transpose(0, 2, 1), view_dirs=R @ inp["view_dirs"],
               lobe_dirs=inp["lobe_dirs"] @ R.T)
    g = ShadingGraph(4, 8)
    a = g(*[torch.from_numpy(np.ascontiguousarray(inp[n])) for n in SHADING_INPUTS]).numpy()
    b = g(*[torch.from_numpy(np.ascontiguousarray(rot[n])) for n in SHADING_INPUTS]).numpy()
    np.testing.assert_allclose(a, b, rtol=1e-4, atol=1e-4 * np.abs(a).max())


def test_shading_onnx_matches_torch_with_dynamic_batch(tmp_path) -> None:
    rng = np.random.default_rng(11)
    inp = random_inputs(rng, 2, 40, 4, 8)
    g = ShadingGraph(4, 8)
    batch = {0: "B"}
    path = export_onnx(g, [torch.from_numpy(inp[n]) for n in SHADING_INPUTS], tmp_path / "shade.onnx",
                       SHADING_INPUTS, ["radiance"],
                       {"visibility": batch, "frames": batch, "view_dirs": batch, "radiance": batch})
    big = random_inputs(np.random.default_rng(12), 5, 40, 4, 8)  # another batch size than traced
    p = check_parity(g, path, big)
    assert p.rel_error <= 1e-4
    assert p.scale > 0

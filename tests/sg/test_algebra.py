"""SG algebra (seed 004 eq. 3-4) against numerical quadrature on the sphere; SGLobes validation and files."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import torch

from prt_torch.errors import PrtError
from prt_torch.sg.algebra import (
    cone_half_angle,
    sg_eval,
    sg_inner,
    sg_integral,
    sg_product,
    sg_triple,
    sharpness_for_half_angle,
)
from prt_torch.sg.lobes import SGLobes
from prt_torch.sh.quadrature import gauss_product_rule

# Gauss-Legendre x uniform-phi rule exact to degree 400: resolves SGs up to lambda ~ 150 to ~1e-10
DIRS, W = (torch.as_tensor(a) for a in gauss_product_rule(400))


def _unit(rng: np.random.Generator, *shape: int) -> torch.Tensor:
    v = rng.normal(size=(*shape, 3))
    return torch.as_tensor(v / np.linalg.norm(v, axis=-1, keepdims=True))


def _g(p: torch.Tensor, lam: torch.Tensor) -> torch.Tensor:
    """An SG of unit amplitude at the quadrature nodes: ``(N,)``."""
    return torch.exp(lam * (DIRS @ p - 1))


def test_integral_and_inner_match_quadrature() -> None:
    rng = np.random.default_rng(1)
    p = _unit(rng, 6)
    lam = torch.tensor([0.05, 0.7, 3.0, 20.0, 60.0, 150.0], dtype=torch.float64)
    mu = torch.as_tensor(rng.uniform(0.2, 2.0, size=(6, 3)))
    ref = torch.stack([(W * _g(p[k], lam[k]))[:, None].sum(0) * mu[k] for k in range(6)])
    torch.testing.assert_close(sg_integral(lam, mu), ref, rtol=1e-9, atol=0)
    for i, j in [(0, 1), (1, 2), (2, 3), (3, 4), (4, 5), (1, 5)]:
        ref = (W * _g(p[i], lam[i]) * _g(p[j], lam[j])).sum() * mu[i] * mu[j]
        torch.testing.assert_close(sg_inner(p[i], lam[i], mu[i], p[j], lam[j], mu[j]), ref, rtol=1e-8, atol=1e-300)


def test_product_is_pointwise_product() -> None:
    rng = np.random.default_rng(2)
    p1, p2 = _unit(rng, 5), _unit(rng, 5)
    l1 = torch.tensor([1.0, 5.0, 30.0, 2.0, 1e4], dtype=torch.float64)
    l2 = torch.tensor([4.0, 0.5, 30.0, 2.0, 7.0], dtype=torch.float64)
    m1, m2 = torch.as_tensor(rng.uniform(0.5, 2, (5, 3))), torch.as_tensor(rng.uniform(0.5, 2, 5))
    p, lam, mu = sg_product(p1, l1, m1, p2, l2, m2)
    assert p.shape == (5, 3) and lam.shape == (5,) and mu.shape == (5, 3)
    d = DIRS[::997]
    lhs = torch.exp(l1 * (d @ p1.T - 1))[..., None] * m1 * (torch.exp(l2 * (d @ p2.T - 1)) * m2)[..., None]
    rhs = torch.exp(lam * (d @ p.T - 1))[..., None] * mu
    torch.testing.assert_close(rhs, lhs, rtol=1e-10, atol=1e-300)
    # opposite axes with equal sharpness: the product is the constant m1 m2 exp(-2 l)
    q, lq, mq = sg_product(p1[0], l1[0], m1[0], -p1[0], l1[0], m1[0])
    assert float(lq) < 1e-9
    torch.testing.assert_close(mq, m1[0] ** 2 * math.exp(-2 * float(l1[0])))


def test_triple_product_eq4_matches_quadrature_and_broadcasts() -> None:
    rng = np.random.default_rng(3)
    V, L, B, S = 2, 3, 2, 4
    lp, bp, vp = _unit(rng, 1, L, 1, 1), _unit(rng, V, 1, B, 1), _unit(rng, V, 1, 1, S)
    ll = torch.as_tensor(rng.uniform(0.5, 40, (1, L, 1, 1)))
    bl = torch.as_tensor(rng.uniform(0.5, 60, (V, 1, B, 1)))
    vl = torch.as_tensor(rng.uniform(0.5, 20, (V, 1, 1, S)))
    lm = torch.as_tensor(rng.uniform(0.1, 3, (1, L, 1, 1, 3)))
    bm = torch.as_tensor(rng.uniform(0.1, 3, (V, 1, B, 1, 3)))
    vm = torch.ones(V, 1, 1, S, dtype=torch.float64)  # scalar visibility amplitudes
    out = sg_triple((lp, ll, lm), (bp, bl, bm), (vp, vl, vm))
    assert out.shape == (V, L, B, S, 3)
    for v, li, b, s in [(0, 0, 0, 0), (1, 2, 1, 3), (0, 1, 1, 2), (1, 0, 0, 1)]:
        f = _g(lp[0, li, 0, 0], ll[0, li, 0, 0]) * _g(bp[v, 0, b, 0], bl[v, 0, b, 0]) \
            * _g(vp[v, 0, 0, s], vl[v, 0, 0, s])
        ref = (W * f).sum() * lm[0, li, 0, 0] * bm[v, 0, b, 0] * vm[v, 0, 0, s]
        torch.testing.assert_close(out[v, li, b, s], ref, rtol=1e-8, atol=0)
    # SGLobes arguments and the scalar-only case
    lobes = SGLobes(lp[0, :, 0, 0], ll[0, :, 0, 0], lm[0, :, 0, 0])
    brdf0 = (bp[0, 0, 0], bl[0, 0, 0], bm[0, 0, 0])
    vis0 = (vp[0, 0, 0, 0], vl[0, 0, 0, 0], vm[0, 0, 0, 0])
    torch.testing.assert_close(sg_triple(lobes, brdf0, vis0), out[0, :, 0, 0])
    sc = sg_triple((lp[0, 0, 0, 0], ll[0, 0, 0, 0], torch.tensor(1.0, dtype=torch.float64)),
                   (bp[0, 0, 0, 0], bl[0, 0, 0, 0], torch.tensor(1.0, dtype=torch.float64)),
                   (vp[0, 0, 0, 0], vl[0, 0, 0, 0], torch.tensor(1.0, dtype=torch.float64)))
    assert sc.shape == ()


def test_float32_is_stable_for_very_sharp_lobes() -> None:
    # eq. 4 as written overflows (exp(l1 + l2 + l3)) in float32 beyond ~88; the evaluated form must not
    p = torch.tensor([0.0, 0.0, 1.0])
    q = torch.nn.functional.normalize(torch.tensor([0.0, 0.01, 1.0]), dim=0)
    lam = torch.tensor(5e4)
    one = torch.tensor(1.0)
    t32 = sg_triple((p, lam, one), (q, lam, one), (p, torch.tensor(10.0), one))
    t64 = sg_triple((p.double(), lam.double(), one.double()), (q.double(), lam.double(), one.double()),
                    (p.double(), torch.tensor(10.0, dtype=torch.float64), one.double()))
    assert torch.isfinite(t32) and float(t64) > 0
    assert abs(float(t32) / float(t64) - 1) < 1e-4
    # a narrow lobe integrates to ~ 2 pi / lambda
    assert abs(float(sg_integral(lam, one)) * float(lam) / (2 * math.pi) - 1) < 1e-5


def test_eval_and_cone_angle() -> None:
    rng = np.random.default_rng(4)
    p, lam, mu = _unit(rng, 4), torch.tensor([1.0, 2.0, 8.0, 30.0], dtype=torch.float64), torch.rand(4, 3).double()
    d = _unit(rng, 10)
    ref = sum(mu[k] * torch.exp(lam[k] * ((d * p[k]).sum(-1, keepdim=True) - 1)) for k in range(4))
    torch.testing.assert_close(sg_eval(p, lam, mu, d), ref)
    torch.testing.assert_close(SGLobes(p, lam, mu).eval(d), ref)
    # eq. 5-6: the SG is 0.5 at the cone half-angle
    a = cone_half_angle(lam)
    torch.testing.assert_close(torch.exp(lam * (torch.cos(a) - 1)), torch.full_like(lam, 0.5))
    torch.testing.assert_close(sharpness_for_half_angle(a), lam)


def test_lobes_validation_files_and_integral(tmp_path: Path) -> None:
    rng = np.random.default_rng(5)
    lobes = SGLobes(_unit(rng, 5), torch.linspace(1, 50, 5, dtype=torch.float64), torch.rand(5, 3).double())
    for name in ("l.json", "l.npz"):
        lobes.save(tmp_path / name)
        back = SGLobes.load(tmp_path / name)
        torch.testing.assert_close(back.axis, lobes.axis)
        torch.testing.assert_close(back.amplitude, lobes.amplitude)
    both = SGLobes.cat([lobes, lobes[1:3]]).to(torch.float32)
    assert len(both) == 7 and both.dtype == torch.float32
    ref = (W[:, None] * sg_eval(lobes.axis, lobes.sharpness, lobes.amplitude, DIRS)).sum(0)
    torch.testing.assert_close(lobes.integral(), ref, rtol=1e-9, atol=0)
    assert len(SGLobes.empty()) == 0


@pytest.mark.parametrize(("kwargs", "match"), [
    ({"sharpness": torch.tensor([1.0, 0.0])}, "lambda"),
    ({"sharpness": torch.tensor([1.0, -2.0])}, "lambda"),
    ({"amplitude": torch.tensor([[1.0, float("nan"), 0], [1, 1, 1]])}, "NaN"),
    ({"axis": torch.tensor([[0.0, 0, 2], [1, 0, 0]])}, "unit"),
    ({"axis": torch.tensor([[0.0, 0, 1]])}, "shape"),
    ({"amplitude": torch.ones(2)}, "shape"),
])
def test_bad_lobes_are_one_line_errors(kwargs: dict, match: str, tmp_path: Path) -> None:
    good = {"axis": torch.tensor([[0.0, 0, 1], [1, 0, 0]]), "sharpness": torch.tensor([1.0, 2.0]),
            "amplitude": torch.ones(2, 3)}
    with pytest.raises(PrtError, match=match) as e:
        SGLobes(**{**good, **kwargs})
    assert "\n" not in str(e.value)


def test_bad_algebra_inputs_are_one_line_errors(tmp_path: Path) -> None:
    p, one = torch.tensor([0.0, 0, 1]), torch.tensor(1.0)
    for call in (lambda: sg_integral(torch.tensor([0.0]), torch.ones(1)),
                 lambda: sg_integral(torch.tensor([float("nan")]), torch.ones(1)),
                 lambda: sg_inner(p, torch.tensor(-1.0), one, p, one, one),
                 lambda: sg_triple((p, one, one), (p, one, one), (p, torch.tensor(0.0), one)),
                 lambda: sg_product(p, one, torch.tensor(float("inf")), p, one, one),
                 lambda: sg_eval(p[None], one[None], one[None], torch.ones(2, 2))):
        with pytest.raises(PrtError) as e:
            call()
        assert "\n" not in str(e.value)
    (tmp_path / "bad.json").write_text("{not json")
    with pytest.raises(PrtError, match="JSON"):
        SGLobes.load(tmp_path / "bad.json")
    (tmp_path / "neg.json").write_text('{"axis": [[0, 0, 1]], "sharpness": [-1], "amplitude": [[1, 1, 1]]}')
    with pytest.raises(PrtError, match="lambda"):
        SGLobes.load(tmp_path / "neg.json")


@pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA device on this machine")
def test_cuda_matches_cpu() -> None:
    rng = np.random.default_rng(6)
    light = (_unit(rng, 1, 8, 1).float(), torch.as_tensor(rng.uniform(1, 100, (1, 8, 1))).float(),
             torch.rand(1, 8, 1, 3))
    brdf = (_unit(rng, 64, 1, 2).float(), torch.as_tensor(rng.uniform(1, 1e4, (64, 1, 2))).float(),
            torch.rand(64, 1, 2))
    vis = (_unit(rng, 64, 1, 1).float(), torch.full((64, 1, 1), 5.0), torch.ones(64, 1, 1))
    cpu = sg_triple(light, brdf, vis)
    gpu = sg_triple(*(tuple(t.cuda() for t in sg) for sg in (light, brdf, vis)))
    torch.testing.assert_close(gpu.cpu(), cpu, rtol=1e-4, atol=1e-7)

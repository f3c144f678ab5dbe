"""SG shading with cone visibility (seed 004 eq. 2-4) against numerical quadrature on the sphere, and the peak
split against pixel sums of the map."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from prt_torch.errors import PrtError
from prt_torch.sg.lobes import SGLobes
from prt_torch.sg.shading import SGLight, shade_sg, split_peaks
from prt_torch.sh.quadrature import sphere_directions

Q = torch.tensor(sphere_directions(400_000, seed=5))  # uniform, weight 4 pi / N


def _sg(axis: torch.Tensor, lam: torch.Tensor, mu: torch.Tensor, d: torch.Tensor) -> torch.Tensor:
    """Sum of SGs ``(..., K)`` at directions ``d (N, 3)`` -> ``(..., N, C)``."""
    g = torch.exp(lam[..., None, :] * (d @ axis.transpose(-1, -2) - 1))  # (..., N, K)
    return g @ mu


def _unit(x: np.ndarray) -> torch.Tensor:
    t = torch.tensor(x, dtype=torch.float64)
    return t / t.norm(dim=-1, keepdim=True)


def _light(n_rest: int = 6, peak: bool = True) -> SGLight:
    rng = np.random.default_rng(2)
    rest = SGLobes(_unit(rng.normal(size=(n_rest, 3)) + [0, 0, 1.0]), torch.tensor(rng.uniform(1, 8, n_rest)),
                   torch.tensor(rng.uniform(0.1, 1.0, (n_rest, 3))))
    if peak:
        pk = SGLobes(_unit(np.array([[0.3, -0.2, 0.9]])), torch.tensor([800.0]), torch.tensor([[900.0, 850.0, 700.0]]))
        idx, pd, ps = torch.zeros(1, dtype=torch.long), pk.axis.clone(), torch.tensor([0.004])
    else:
        pk = SGLobes.empty(torch.float64)
        idx, pd, ps = torch.zeros(0, dtype=torch.long), torch.zeros(0, 3, dtype=torch.float64), torch.zeros(0)
    return SGLight(rest, pk, idx, pd, ps.double(), [0.0])


def _brdf() -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Two vertices x two lobes (a diffuse cosine lobe about n, a glossy one about a mirror direction)."""
    n = _unit(np.array([[0.0, 0.0, 1.0], [0.2, 0.1, 0.97]]))
    r = _unit(np.array([[0.4, 0.0, 0.9], [0.1, -0.3, 0.95]]))
    axis = torch.stack([n, r], dim=1)  # (V, J, 3)
    lam = torch.tensor([[2.133, 30.0], [2.133, 12.0]], dtype=torch.float64)
    mu = torch.tensor([[[0.37, 0.3, 0.25], [2.0, 2.0, 2.0]], [[0.37, 0.3, 0.25], [1.0, 1.2, 1.0]]],
                      dtype=torch.float64)
    return axis, lam, mu


def _cones(axis: torch.Tensor, lam: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    from prt_torch.vct.cones import pack_lobe_cones  # test helper only: the cones of the lobes

    d, h, _ = pack_lobe_cones(axis, lam, 7)
    return d, h


def _quadrature(light: SGLight, axis: torch.Tensor, lam: torch.Tensor, mu: torch.Tensor,
                vis: torch.Tensor | None = None) -> torch.Tensor:
    """``int L(w) rho(w) V(w) dw`` per vertex by quadrature; ``vis (V, N)`` or None (1)."""
    lo = light.all_lobes()
    lw = _sg(lo.axis, lo.sharpness, lo.amplitude, Q)  # (N, 3)
    rho = _sg(axis, lam, mu, Q)  # (V, N, 3)
    f = lw[None] * rho * (1 if vis is None else vis[..., None])
    return f.sum(1) * 4 * math.pi / Q.shape[0]


def test_unoccluded_equals_the_double_product_by_quadrature() -> None:
    light = _light()
    axis, lam, mu = _brdf()
    d, h = _cones(axis, lam)
    ones = torch.ones(d.shape[:-1], dtype=torch.float64)
    got = shade_sg(light, axis, lam, mu, d, h, ones, torch.ones(2, 1, dtype=torch.float64))
    np.testing.assert_allclose(got.numpy(), _quadrature(light, axis, lam, mu).numpy(), rtol=2e-3)
    # without peak cones (the ablation) the unoccluded result is the same
    got2 = shade_sg(light, axis, lam, mu, d, h, ones, None)
    np.testing.assert_allclose(got2.numpy(), got.numpy(), rtol=1e-9)
    # fully occluded: nothing
    zero = shade_sg(light, axis, lam, mu, d, h, 0 * ones, torch.zeros(2, 1, dtype=torch.float64))
    assert float(zero.abs().max()) == 0.0


def test_peak_cone_carries_exactly_the_peak() -> None:
    light = _light()
    axis, lam, mu = _brdf()
    d, h = _cones(axis, lam)
    ones = torch.ones(d.shape[:-1], dtype=torch.float64)
    shadowed = shade_sg(light, axis, lam, mu, d, h, ones, torch.zeros(2, 1, dtype=torch.float64))
    rest_only = SGLight(light.lobes, SGLobes.empty(torch.float64), light.peak_index[:0], light.peak_dirs[:0],
                        light.peak_solid_angle[:0], [0.0])
    np.testing.assert_allclose(shadowed.numpy(), _quadrature(rest_only, axis, lam, mu).numpy(), rtol=2e-3)


def test_directional_occlusion_follows_the_light() -> None:
    """A sharp light lobe (lambda 2000) and sub-cones occluded on one side: the shading equals the quadrature of
    L rho V with V the cones' visibility interpolated at the light (their SGs' normalised weights there)."""
    axis, lam, mu = _brdf()
    d, h = _cones(axis, lam)
    s = _unit(np.array([[0.5, 0.0, 0.85]]))
    light = SGLight(SGLobes(s, torch.tensor([2000.0], dtype=torch.float64), torch.tensor([[500.0, 500.0, 500.0]],
                                                                                        dtype=torch.float64)),
                    SGLobes.empty(torch.float64), torch.zeros(0, dtype=torch.long), torch.zeros(0, 3).double(),
                    torch.zeros(0).double(), [0.0])
    vis = ((d @ s[0]) < 0.9).double()  # cones pointing near the light are blocked
    got = shade_sg(light, axis, lam, mu, d, h, vis)
    lam_c = math.log(0.5) / (torch.cos(h) - 1)
    g = torch.exp(lam_c * ((d @ s[0]) - 1))  # (V, J, C) cone SGs at the light
    v_at = (g * vis).sum(-1) / g.sum(-1)  # (V, J)
    rho_at = torch.exp(lam * ((axis @ s[0]) - 1))[..., None] * mu  # (V, J, 3)
    power = 500.0 * 2 * math.pi / 2000.0 * (1 - math.exp(-4000.0))
    ref = power * (rho_at * v_at[..., None]).sum(1)
    np.testing.assert_allclose(got.numpy(), ref.numpy(), rtol=0.03)
    unocc = shade_sg(light, axis, lam, mu, d, h, torch.ones_like(vis))
    assert (got < 0.9 * unocc).all()


def test_split_peaks_conserves_the_map() -> None:
    from prt_torch.light.envmap import EnvMap
    from prt_torch.sg.lighting import detect_peaks

    h = 128
    from prt_torch.light.envmap import latlong_directions

    d = latlong_directions(h, 2 * h)
    sun = np.array([0.3, -0.4, 0.866])
    sun /= np.linalg.norm(sun)
    img = 0.5 + 0.3 * np.clip(d[..., 2:3], 0, 1) * np.array([0.6, 0.8, 1.0])
    img = img + 2000.0 * (d @ sun >= math.cos(math.radians(3.0)))[..., None]
    env = EnvMap(img.astype(np.float32), "latlong")
    peaks = detect_peaks(env)
    assert len(peaks) == 1
    rest, powers = split_peaks(env, peaks)
    om = env.solid_angles()[..., None]
    total = (env.image.astype(np.float64) * om).sum((0, 1))
    np.testing.assert_allclose((rest.image.astype(np.float64) * om).sum((0, 1)) + powers[0], total, rtol=1e-5)
    disk = (2000.0 * (d @ sun >= math.cos(math.radians(3.0)))[..., None] * om).sum((0, 1))
    np.testing.assert_allclose(powers[0], np.repeat(disk, 3), rtol=0.02)  # the disk's power, background kept
    assert rest.image.max() < 2.0


def test_bad_input_is_one_line_errors() -> None:
    light = _light()
    axis, lam, mu = _brdf()
    d, h = _cones(axis, lam)
    ones = torch.ones(d.shape[:-1], dtype=torch.float64)
    with pytest.raises(PrtError, match="lambda") as e:
        shade_sg(light, axis, -lam, mu, d, h, ones)
    assert "\n" not in str(e.value)
    with pytest.raises(PrtError, match="NaN"):
        shade_sg(light, axis, lam, mu, d, h, ones * float("nan"))
    with pytest.raises(PrtError, match="peak visibility"):
        shade_sg(light, axis, lam, mu, d, h, ones, torch.ones(2, 3, dtype=torch.float64))

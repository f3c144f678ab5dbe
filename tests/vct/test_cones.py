"""Cone selection (seed 004 eq. 5-6, Fig. 4) against closed forms and numerical quadrature on the sphere."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from prt_torch.errors import PrtError
from prt_torch.sh.quadrature import sphere_directions
from prt_torch.vct import cone_aperture, cone_sharpness, pack_lobe_cones, peak_cones
from prt_torch.vct.cones import MIN_HALF_ANGLE, cones_per_lobe, lobe_extent


def test_aperture_is_where_the_sg_halves() -> None:
    lam = torch.tensor([0.5, 2.133, 10.0, 100.0, 5000.0], dtype=torch.float64)
    a = cone_aperture(lam)
    np.testing.assert_allclose(torch.exp(lam * (torch.cos(a) - 1)).numpy(), 0.5, rtol=1e-9)  # eq. 5
    np.testing.assert_allclose(cone_sharpness(a).numpy(), lam.numpy(), rtol=1e-9)
    assert float(cone_aperture(torch.tensor([0.2]))) == pytest.approx(math.pi)  # never halves on the sphere


@pytest.mark.parametrize("lam", [2.133, 8.0, 40.0])
def test_seven_cone_packing_covers_the_lobe(lam: float) -> None:
    rng = np.random.default_rng(0)
    axis = torch.tensor(rng.normal(size=(5, 3)))
    axis = axis / axis.norm(dim=-1, keepdim=True)
    dirs, half, w = pack_lobe_cones(axis, torch.full((5,), lam, dtype=torch.float64), 7)
    assert dirs.shape == (5, 7, 3) and half.shape == (5, 7) and w.shape == (5, 7)
    np.testing.assert_allclose(w.sum(-1).numpy(), 1.0, atol=1e-12)
    ext = float(lobe_extent(torch.tensor(lam, dtype=torch.float64)))
    beta = ext / 3
    ang = torch.acos((dirs * axis[:, None]).sum(-1).clamp(-1, 1)).numpy()
    np.testing.assert_allclose(ang[:, 0], 0.0, atol=1e-6)       # the centre cone is the lobe axis
    np.testing.assert_allclose(ang[:, 1:], 2 * beta, atol=1e-6)  # the ring is tangent to it ...
    assert (ang + half.numpy() <= ext + 1e-6).all()               # ... and every cone lies within the lobe extent
    np.testing.assert_allclose(half.numpy(), beta, atol=1e-9)
    # ring neighbours (the planar hexagonal packing laid on the sphere) overlap a little: their centres stay
    # >= 0.85 x 2 beta apart (51 of 60 degrees for the 90-degree Lambert extent)
    d1, d2 = dirs[:, 1], dirs[:, 2]
    assert (torch.acos((d1 * d2).sum(-1)).numpy() >= 2 * beta * 0.85).all()
    # weights = the lobe's integral over each cell (centre cap, 60-degree sectors), by quadrature on the sphere
    q = torch.tensor(sphere_directions(200_000, seed=1))
    g = torch.exp(lam * (q @ axis[0] - 1))
    t1 = dirs[0, 1] - (dirs[0, 1] @ axis[0]) * axis[0]
    t1 = t1 / t1.norm()
    t2 = torch.cross(axis[0], t1, dim=0)
    theta = torch.acos((q @ axis[0]).clamp(-1, 1))
    phi = torch.remainder(torch.atan2(q @ t2, q @ t1) + math.pi / 6, 2 * math.pi)
    cell = torch.where(theta < beta, torch.zeros_like(phi, dtype=torch.long), 1 + (phi // (math.pi / 3)).long())
    ref = torch.zeros(7, dtype=torch.float64).index_add_(0, cell, g) / g.sum()
    np.testing.assert_allclose(w[0].numpy(), ref.numpy(), atol=2e-3)


def test_specular_lobes_get_one_cone_and_peaks_get_theirs() -> None:
    assert cones_per_lobe(2.133) == 7 and cones_per_lobe(5000.0) == 1
    axis = torch.tensor([[0.0, 0.0, 1.0]], dtype=torch.float64)
    d, h, w = pack_lobe_cones(axis, torch.tensor([5000.0], dtype=torch.float64), 1)
    assert d.shape == (1, 1, 3) and float(w) == 1.0
    assert float(h) == pytest.approx(float(cone_aperture(torch.tensor([5000.0], dtype=torch.float64))), rel=1e-9)
    # a peak's cone is the cap of its solid angle
    omega = torch.tensor([0.01, 1e-6], dtype=torch.float64)
    pd, ph = peak_cones(torch.tensor([[0.0, 0.0, 2.0], [1.0, 0.0, 0.0]], dtype=torch.float64), omega)
    np.testing.assert_allclose(pd.norm(dim=-1).numpy(), 1.0)
    assert float(2 * math.pi * (1 - math.cos(float(ph[0])))) == pytest.approx(0.01, rel=1e-9)
    assert float(ph[1]) == pytest.approx(MIN_HALF_ANGLE)


def test_bad_lobes_are_one_line_errors() -> None:
    axis = torch.tensor([[0.0, 0.0, 1.0]])
    for bad in (0.0, -1.0, float("nan")):
        with pytest.raises(PrtError, match="lambda") as e:
            pack_lobe_cones(axis, torch.tensor([bad]), 7)
        assert "\n" not in str(e.value)
        with pytest.raises(PrtError, match="lambda"):
            cone_aperture(torch.tensor([bad]))
    with pytest.raises(PrtError, match="lambda"):
        cones_per_lobe(0.0)
    with pytest.raises(PrtError, match="n_cones"):
        pack_lobe_cones(axis, torch.tensor([2.0]), 3)
    with pytest.raises(PrtError, match="NaN"):
        peak_cones(torch.tensor([[float("nan"), 0.0, 1.0]]), torch.tensor([0.1]))

"""Wedge SH tables and the z-rotation path against independent references (quadrature, closed forms, Ivanic)."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from prt_torch.heightfield.wedges import WedgeTable, canonical_wedge
from prt_torch.heightfield.zrotation import ZRotator
from prt_torch.sh.basis import sh_basis
from prt_torch.sh.quadrature import random_rotations, rotations_about_z, sphere_directions
from prt_torch.sh.rotation import sh_rotation
from prt_torch.sh.zonal import hemisphere_zh, zh_to_sh

N_QUAD = 200_000


@pytest.fixture(scope="module")
def sphere() -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    d = sphere_directions(N_QUAD)
    return d, sh_basis(d, 4), np.arcsin(np.clip(d[:, 2], -1, 1)), np.arctan2(d[:, 1], d[:, 0])


@pytest.mark.parametrize("n_wedges", [1, 5, 16])
def test_rotated_wedges_match_quadrature_of_the_indicator(sphere, n_wedges: int) -> None:
    """T_i(x) = SH of {|phi - phi_i| <= pi/n, elevation <= x}: equal-area spherical-Fibonacci quadrature of the
    indicator (discontinuous, so converges slowly: ~1e-5 at 2e5 points; tolerance 2e-4)."""
    d, y, el, az = sphere
    table = WedgeTable.make(4, n_wedges)
    w = 4 * np.pi / d.shape[0]
    for i in sorted({0, n_wedges // 2, n_wedges - 1}):
        dphi = np.angle(np.exp(1j * (az - table.azimuths[i])))
        for x in (-1.2, -0.3, 0.0, 0.4, 1.3):
            ind = (np.abs(dphi) <= np.pi / n_wedges) & (el <= x)
            ref = (ind[:, None] * y).sum(0) * w
            got = table.lookup(np.full(n_wedges, x))[i]
            np.testing.assert_allclose(got, ref, atol=2e-4)


def test_wedges_sum_to_closed_forms() -> None:
    """All wedges together below elevation 0 = the lower hemisphere; below pi/2 = the whole sphere (float64)."""
    table = WedgeTable.make(4, 8)
    lower = table.lookup(np.zeros(8)).sum(0)
    full = np.zeros(16)
    full[0] = np.sqrt(4 * np.pi)
    upper = zh_to_sh(hemisphere_zh(4), np.array([0.0, 0.0, 1.0]))
    np.testing.assert_allclose(lower, full - upper, atol=1e-12)
    np.testing.assert_allclose(table.lookup(np.full(8, np.pi / 2)).sum(0), full, atol=1e-12)
    x, w = canonical_wedge(4, 8)
    assert x[0] == -np.pi / 2 and np.all(w[0] == 0)


def test_z_rotator_matches_ivanic() -> None:
    """D(F) v by three z-rotations and two fixed matrices == sh_rotation(F) v (any rotation, incl. b = 0, pi)."""
    rots = np.concatenate([random_rotations(200, seed=3), rotations_about_z(np.linspace(-3, 3, 7)),
                           np.diag([1.0, -1.0, -1.0])[None]])
    v = np.random.default_rng(0).normal(size=(rots.shape[0], 25))
    ref = np.einsum("vij,vj->vi", sh_rotation(rots, 5), v)
    got = ZRotator(5, torch.float64)(torch.as_tensor(v.T.copy()), torch.as_tensor(rots)).numpy().T
    np.testing.assert_allclose(got, ref, atol=1e-12)

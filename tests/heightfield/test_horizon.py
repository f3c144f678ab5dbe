"""Max-pyramid horizon angles against an exhaustive scan of the grid (brute force, numpy)."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from prt_torch.heightfield.horizon import REACH, SearchSchedule, horizon_angles, max_pyramid, wedge_azimuths
from prt_torch.heightfield.surface import Terrain, Waves, gradient
from tests.tolerance import assert_bitwise


def brute_force_horizons(h: np.ndarray, n_wedges: int, extent: float = 1.0, step: float = 0.25) -> np.ndarray:
    """``(N, N, n)`` exhaustive horizons: march every vertex's wedge-centre ray across the whole grid in
    ``step``-texel steps, bilinear heights, max elevation angle (-pi/2 if the ray leaves at once)."""
    n = h.shape[0]
    dx = extent / (n - 1)
    iy, ix = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
    out = np.full((n, n, n_wedges), -np.inf)
    for i, phi in enumerate(wedge_azimuths(n_wedges)):
        for d in np.arange(step, math.sqrt(2) * n, step):
            x, y = ix + d * math.cos(phi), iy + d * math.sin(phi)
            ok = (x >= -1e-9) & (x <= n - 1 + 1e-9) & (y >= -1e-9) & (y <= n - 1 + 1e-9)
            x, y = np.clip(x, 0, n - 1), np.clip(y, 0, n - 1)
            x0, y0 = np.clip(np.floor(x).astype(int), 0, n - 2), np.clip(np.floor(y).astype(int), 0, n - 2)
            fx, fy = x - x0, y - y0
            v = ((1 - fy) * ((1 - fx) * h[y0, x0] + fx * h[y0, x0 + 1])
                 + fy * ((1 - fx) * h[y0 + 1, x0] + fx * h[y0 + 1, x0 + 1]))
            out[..., i] = np.maximum(out[..., i], np.where(ok, (v - h) / (d * dx), -np.inf))
    return np.arctan(out)


def _effective(ang: np.ndarray, h: np.ndarray, n_wedges: int) -> np.ndarray:
    """max(horizon, tangent-plane elevation): what the visibility uses (lower horizons occlude nothing)."""
    g = gradient(h)
    az = wedge_azimuths(n_wedges)
    return np.maximum(ang, np.arctan(g[..., :1] * np.cos(az) + g[..., 1:] * np.sin(az)))


@pytest.mark.parametrize("gen", [Waves(40, seed=1), Terrain(40, seed=2)], ids=["waves", "terrain"])
def test_pyramid_horizons_match_exhaustive_scan(gen) -> None:
    """Effective horizons within 1 deg on average and 8 deg at the 99th percentile of the exhaustive scan.

    Why these bounds: a level-L sample stands for a window of half-width <= d / (2 rho) (8 % of the distance at
    rho = 6) whose max is placed at the window centre, and level-0 samples are 1 texel apart vs the scan's 1/4;
    both matter only near sharp crests (a crest between two level-0 samples a few texels away moves the
    horizon by degrees), so the mean stays ~0.5 deg while the 99th percentile reaches ~7 deg on sharpened waves."""
    h = gen(0.7)
    n_w = 8
    ref = np.degrees(_effective(brute_force_horizons(h, n_w), h, n_w))
    got = np.degrees(_effective(horizon_angles(torch.as_tensor(h), n_w, 1.0).double().numpy(), h, n_w))
    err = np.abs(got - ref)
    print(f"horizon error: mean {err.mean():.3f} deg, p99 {np.percentile(err, 99):.3f} deg")
    assert err.mean() < 1.0, err.mean()
    assert np.percentile(err, 99) < 8.0, np.percentile(err, 99)
    # the raw angles too (no clamp): -90 exactly where the scan finds nothing (rays leaving the grid)
    raw = horizon_angles(torch.as_tensor(h), n_w, 1.0).double().numpy()
    bf = brute_force_horizons(h, n_w)
    np.testing.assert_array_equal(raw == -np.pi / 2, bf == -np.pi / 2)


def test_step_horizon_is_exact_on_the_axis() -> None:
    """A cliff of height H along +x seen from the plain at distance D texels (axis-aligned, exact samples
    within 3 rho texels): horizon = atan(H / (D dx)) exactly, and -pi/2 looking away across the edge."""
    n, cliff, hgt = 24, 14, 0.2
    h = np.zeros((n, n))
    h[:, cliff:] = hgt
    ang = horizon_angles(torch.as_tensor(h), 4, 1.0).double().numpy()  # wedge 0 looks along +x
    dx = 1.0 / (n - 1)
    for ix in range(cliff - 8, cliff):
        d = cliff - ix
        np.testing.assert_allclose(ang[5, ix, 0], math.atan(hgt / (d * dx)), rtol=1e-6)
    assert np.all(ang[:, 0, 2] == -np.pi / 2)  # wedge 2 looks along -x: off the grid at column 0


@pytest.mark.parametrize("n", [37, 39])
def test_stride_interpolates_from_searched_vertices(n: int) -> None:
    """With stride s the searched vertices (multiples of s, and the last row/column) equal the full search
    (n = 37: the last index is on the lattice; n = 39: it is searched separately)."""
    h = Waves(n, seed=4)(0.2)
    full = horizon_angles(torch.as_tensor(h), 6, 1.0, stride=1)
    sub = horizon_angles(torch.as_tensor(h), 6, 1.0, stride=4)
    idx = sorted(set(range(0, n, 4)) | {n - 1})
    torch.testing.assert_close(sub[idx][:, idx], full[idx][:, idx])
    assert sub.shape == full.shape


def test_max_pyramid_and_schedule() -> None:
    """Level L = max over the centred 3^L window (scipy's maximum_filter); O(log N) samples, tiling the ray."""
    from scipy.ndimage import maximum_filter

    h = np.random.default_rng(0).normal(size=(50, 50))
    pyr = max_pyramid(torch.as_tensor(h), 3).numpy()
    for level in range(3):
        ref = maximum_filter(h, size=3 ** level, mode="constant", cval=-np.inf)
        assert_bitwise(pyr[level], ref, why='a maximum rounds nothing: both are the same input values')
    s = SearchSchedule.make(512)
    assert s.n_samples <= 60 and s.distance.max() <= math.sqrt(2) * 511
    radius = (3.0 ** s.level - 1) / 2
    assert np.all(radius <= s.distance / (2 * REACH) + 1e-9)  # window half-width <= d / (2 rho)
    gaps = s.distance[1:] - s.distance[:-1]
    assert np.all(gaps <= radius[1:] + radius[:-1] + 1 + 1e-9)  # consecutive windows leave no gap

"""The Embree peak-visibility oracle (issue 27 item 2, ``exact``): its disc samples, and simple scenes with known
answers -- fully lit (1), fully shadowed (0), a disc cut by a straight edge (the closed form of a cap cut by a plane,
0.5 at the edge), a disc cut by the receiver's horizon. Sampling tolerances: ``TOL_SIGMA`` binomial standard
deviations of the ``S`` samples of a disc (stratified sampling errs less), plus one sample for the discreteness."""

from __future__ import annotations

import math

import numpy as np
import pytest

from prt_torch.bake.embree import RayScene
from prt_torch.bake.peaks import cap_directions, disc_samples, exact_peak_visibility
from prt_torch.blockers.cones import cap_intersection, cap_solid_angle, horizon_fraction
from prt_torch.errors import PrtError
from tests.tolerance import assert_bitwise

TOL_SIGMA = 5.0  # per receiver; with ~100 receivers a test fails by chance with probability < 1e-4


def binomial_tol(p: np.ndarray, n: int) -> np.ndarray:
    """``TOL_SIGMA`` binomial standard deviations of a share ``p`` estimated from ``n`` samples, plus ``1 / n``."""
    return TOL_SIGMA * np.sqrt(np.asarray(p) * (1 - np.asarray(p)) / n) + 1.0 / n


def quad(x0: float, x1: float, y0: float, y1: float, z: float) -> tuple[np.ndarray, np.ndarray]:
    """A horizontal rectangle at height ``z``: ``(4, 3)`` vertices, ``(2, 3)`` faces."""
    v = np.array([[x0, y0, z], [x1, y0, z], [x1, y1, z], [x0, y1, z]], dtype=np.float64)
    return v, np.array([[0, 1, 2], [0, 2, 3]])


def test_disc_samples_are_stratified_and_equal_area() -> None:
    d = disc_samples(16, seed=3)
    assert d.shape == (256, 2)
    rho2 = (d * d).sum(1)
    assert (rho2 <= 1).all()
    # concentric map: the square ring k (max(|u|, |v|) in [k/8, (k+1)/8), 4 (2k + 1) cells) -> the annulus k
    ring = np.floor(np.sqrt(rho2) * 8).astype(int)
    assert np.array_equal(np.bincount(ring, minlength=8), 4 * (2 * np.arange(8) + 1))
    assert_bitwise(d, disc_samples(16, seed=3), why="the same seeded call twice")
    assert not np.array_equal(d, disc_samples(16, seed=4))
    assert np.array_equal(disc_samples(1, seed=None), [[0.0, 0.0]])  # the cell centres


def test_cap_directions_cover_the_cap_by_equal_solid_angles() -> None:
    r = np.array([0.004, 0.3])
    axis = np.array([[0.0, 0.0, 1.0], [0.6, 0.0, 0.8]])
    w = cap_directions(axis, r, disc_samples(32, seed=None))  # (P, S, 3)
    assert np.allclose(np.linalg.norm(w, axis=-1), 1.0)
    ang = np.arccos(np.clip(np.einsum("psk,pk->ps", w, axis), -1, 1))
    assert (ang <= r[:, None] * (1 + 1e-6)).all()
    # equal area: half of the samples in the inner cap of half the solid angle (one ring of strata of slack)
    inner = (1 - np.cos(ang)) < (1 - np.cos(r[:, None])) / 2
    assert np.all(np.abs(inner.mean(1) - 0.5) <= 2 / 32)


def test_fully_lit_and_fully_shadowed() -> None:
    recv = np.stack([np.linspace(-0.5, 0.5, 11), np.zeros(11), np.zeros(11)], 1)
    up = np.tile([0.0, 0.0, 1.0], (11, 1))
    dirs, radii = np.array([[0.0, 0.0, 1.0], [0.6, 0.0, 0.8]]), np.radians([2.0, 10.0])
    floor_v, floor_f = quad(-5, 5, -5, 5, 0.0)
    lit = exact_peak_visibility(recv, up, dirs, radii, 1e-4, scene=RayScene(floor_v, floor_f))
    assert lit.shape == (11, 2) and lit.dtype == np.float32
    assert (lit == 1).all()
    roof_v, roof_f = quad(-50, 50, -50, 50, 1.0)
    dark = exact_peak_visibility(recv, up, dirs, radii, 1e-4, scene=RayScene(roof_v, roof_f))
    assert (dark == 0).all()


@pytest.mark.parametrize("radius_deg", [0.265, 10.0])
def test_a_straight_edge_cuts_the_disc_as_the_closed_form(radius_deg: float) -> None:
    """A half-plane ``z = 1, x < 0`` above receivers ``(x0, 0, 0)``: the escaping directions are a hemisphere whose
    pole ``(1, 0, x0) / |.|`` is ``gamma = acos(x0 / sqrt(1 + x0^2))`` from the light, so the visible share is
    ``cap_intersection(r, pi/2, gamma) / Omega_r`` -- 0.5 under the edge."""
    r = math.radians(radius_deg)
    x0 = np.linspace(-1.5, 1.5, 61) * math.tan(r)
    recv = np.stack([x0, np.zeros_like(x0), np.zeros_like(x0)], 1)
    up = np.tile([0.0, 0.0, 1.0], (x0.size, 1))
    v, f = quad(-50, 0, -50, 50, 1.0)
    side = 16
    vis = exact_peak_visibility(recv, up, np.array([[0.0, 0.0, 1.0]]), np.array([r]), 0.0, scene=RayScene(v, f),
                                side=side)[:, 0]
    gamma = np.arccos(x0 / np.sqrt(1 + x0 * x0))
    want = cap_intersection(np.full_like(x0, r), np.full_like(x0, math.pi / 2), gamma) / cap_solid_angle(
        np.full_like(x0, r))
    assert np.all(np.abs(vis - want) <= binomial_tol(want, side * side))
    assert abs(vis[30] - 0.5) <= binomial_tol(0.5, side * side)
    assert vis[0] == 0 and vis[-1] == 1


def test_the_horizon_cuts_the_disc_samples_below_it_count_as_not_visible() -> None:
    r = math.radians(10.0)
    tilt = math.pi / 2 + np.linspace(-1.2, 1.2, 41) * r  # the normal's angle from the light
    nrm = np.stack([np.sin(tilt), np.zeros_like(tilt), np.cos(tilt)], 1)
    recv = np.zeros((tilt.size, 3))
    far_v, far_f = quad(100, 101, 100, 101, -100.0)  # nothing in the way
    side = 16
    vis = exact_peak_visibility(recv, nrm, np.array([[0.0, 0.0, 1.0]]), np.array([r]), 1e-4,
                                scene=RayScene(far_v, far_f), side=side)[:, 0]
    want = horizon_fraction(nrm, np.array([[0.0, 0.0, 1.0]]), np.array([r]))[:, 0]
    assert np.all(np.abs(vis - want) <= binomial_tol(want, side * side))
    assert vis[0] == 1 and vis[-1] == 0


def test_chunks_and_seed_are_deterministic() -> None:
    rng = np.random.default_rng(0)
    recv = np.c_[rng.uniform(-0.2, 0.2, (50, 2)), np.zeros(50)]
    up = np.tile([0.0, 0.0, 1.0], (50, 1))
    v, f = quad(-50, 0, -50, 50, 1.0)
    dirs, radii = np.array([[0.0, 0.0, 1.0], [0.0, 0.6, 0.8]]), np.radians([5.0, 8.0])
    a = exact_peak_visibility(recv, up, dirs, radii, 1e-4, scene=RayScene(v, f))
    b = exact_peak_visibility(recv, up, dirs, radii, 1e-4, scene=RayScene(v, f), max_rays=200)
    assert_bitwise(a, b, why="the same rays in other Embree calls: each ray's answer is its own")
    c = exact_peak_visibility(recv, up, dirs, radii, 1e-4, scene=RayScene(v, f), seed=1)
    assert not np.array_equal(a, c)
    # faces= builds the scene of the receivers' own mesh
    m = exact_peak_visibility(v, np.tile([0.0, 0.0, -1.0], (4, 1)), dirs, radii, 1e-4, faces=f)
    assert m.shape == (4, 2) and (m == 0).all()  # facing down, the lights are below their horizon


def test_bad_input_is_one_line() -> None:
    v, f = quad(-1, 1, -1, 1, 1.0)
    p, n = np.zeros((2, 3)), np.tile([0.0, 0.0, 1.0], (2, 1))
    d, r = np.array([[0.0, 0.0, 1.0]]), np.array([0.1])
    for kwargs, msg in ((dict(), "exactly one of faces"), (dict(faces=f, scene=RayScene(v, f)), "exactly one"),):
        with pytest.raises(PrtError, match=msg):
            exact_peak_visibility(p, n, d, r, 1e-4, **kwargs)
    with pytest.raises(PrtError, match=r"angular radii must be in \(0, pi/2\]"):
        exact_peak_visibility(p, n, d, np.array([0.0]), 1e-4, scene=RayScene(v, f))
    with pytest.raises(PrtError, match="unit vectors"):
        exact_peak_visibility(p, n, 2 * d, r, 1e-4, scene=RayScene(v, f))
    with pytest.raises(PrtError, match=r"peak angular radii must have shape \(P,\)"):
        exact_peak_visibility(p, n, d, np.array([0.1, 0.2]), 1e-4, scene=RayScene(v, f))

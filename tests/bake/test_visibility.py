"""Local-frame SH visibility against closed forms (hemisphere indicator, spherical caps)."""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
import pytest
import trimesh
from scipy.special import eval_legendre

from prt_torch.bake.embree import RayScene
from prt_torch.bake.trace import RaySet, trace_frame
from prt_torch.bake.visibility import project_visibility, projection_table, rotate_sh_z
from prt_torch.errors import PrtError
from prt_torch.sh.basis import sh_basis

ORDER = 4


def cap_lambda(l: int, c0: float) -> float:
    """Funk-Hecke eigenvalue of the cap indicator ``{x >= c0}``: ``2 pi int_c0^1 P_l(x) dx`` (scipy Legendre)."""
    if l == 0:
        return 2 * math.pi * (1 - c0)
    return 2 * math.pi * (eval_legendre(l - 1, c0) - eval_legendre(l + 1, c0)) / (2 * l + 1)


def cap_sh(axis: np.ndarray, c0: float, order: int) -> np.ndarray:
    """SH of the indicator of the cap ``{w : w.axis >= c0}`` (Funk-Hecke: ``lambda_l y_lm(axis)``)."""
    y = sh_basis(np.asarray(axis, dtype=np.float64), order)
    lam = np.array([cap_lambda(l, c0) for l in range(order) for _ in range(2 * l + 1)])
    return lam * y


def frame_about_z(angle: float) -> np.ndarray:
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]])


@pytest.fixture(scope="module")
def plane_mesh() -> trimesh.Trimesh:
    plane = trimesh.creation.box(extents=(200.0, 200.0, 1.0))
    plane.apply_translation((0.0, 0.0, -0.5))
    return plane


def mc_sigma(visible: Callable[[np.ndarray], np.ndarray], order: int, n_rays: int) -> np.ndarray:
    """Plain Monte Carlo standard error of every SH coefficient of a 0/1 function on the upper hemisphere.

    The estimator of coefficient i from ``n_rays`` uniform hemisphere samples is the mean of
    ``2 pi V y_i``; its standard error is estimated from a dense independent sample.
    """
    rng = np.random.default_rng(0)
    d = rng.normal(size=(200_000, 3))
    d[:, 2] = np.abs(d[:, 2])
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    vis = visible(d).astype(np.float64)
    return np.std(2 * math.pi * vis[:, None] * sh_basis(d, order), axis=0) / math.sqrt(n_rays)


def test_open_plane_sees_hemisphere_indicator(plane_mesh: trimesh.Trimesh) -> None:
    """A vertex on an open plane: every upper ray escapes, so v = SH of the hemisphere indicator (closed form)."""
    scene = RayScene(plane_mesh.vertices, plane_mesh.faces)
    rng = np.random.default_rng(1)
    pts = np.c_[rng.uniform(-5, 5, (6, 2)), np.zeros(6)]
    frames = np.stack([frame_about_z(a) for a in rng.uniform(0, 2 * math.pi, 6)])
    rays = RaySet.make(512, ORDER, 6, seed=0)
    vis = trace_frame(pts, frames, None, rays, offset=1e-4, scene=scene).visibility
    ref = cap_sh(np.array([0.0, 0.0, 1.0]), 0.0, ORDER)
    # every ray is visible: the only error is the quadrature error of the low-discrepancy set, far
    # below the plain Monte Carlo error 2 pi max|y| / 2 / sqrt(512) ~ 0.08 of a 0/1 integrand
    np.testing.assert_allclose(vis[:, 0], ref[0], rtol=1e-5)  # DC is exact: sum of 2 pi / R
    np.testing.assert_allclose(vis, np.broadcast_to(ref, vis.shape), atol=0.012)
    assert ref[0] == pytest.approx(2 * math.pi / math.sqrt(4 * math.pi))


@pytest.mark.parametrize("tilt", [0.0, 0.5])
def test_plane_under_sphere_loses_cap(plane_mesh: trimesh.Trimesh, tilt: float) -> None:
    """Plane under a sphere: visible = hemisphere minus a cap of half-angle asin(r/h) (closed-form ZH)."""
    h, rho = 2.0, 1.0
    axis = np.array([math.sin(tilt), 0.0, math.cos(tilt)])
    sphere = trimesh.creation.icosphere(subdivisions=5, radius=rho)
    sphere.apply_translation(h * axis)
    mesh = trimesh.util.concatenate([plane_mesh, sphere])
    scene = RayScene(mesh.vertices, mesh.faces)
    c0 = math.sqrt(1 - (rho / h) ** 2)
    frame = frame_about_z(1.1)
    n_rays = 2048
    rays = RaySet.make(n_rays, ORDER, 1, seed=5)
    vis = trace_frame(np.zeros((1, 3)), frame[None], None, rays, offset=1e-5, scene=scene).visibility[0]
    axis_local = frame @ axis
    ref = cap_sh(np.array([0.0, 0.0, 1.0]), 0.0, ORDER) - cap_sh(axis_local, c0, ORDER)
    cap_solid_angle = 2 * math.pi * (1 - c0)
    y00 = 1 / math.sqrt(4 * math.pi)
    assert ref[0] == pytest.approx((2 * math.pi - cap_solid_angle) * y00)
    assert vis[0] == pytest.approx((2 * math.pi - cap_solid_angle) * y00, abs=0.01)
    sigma = mc_sigma(lambda d: (d @ axis_local) < c0, ORDER, n_rays)
    # low-discrepancy + random rotation beats plain MC; allow 3 plain-MC sigmas (+ tessellation slack)
    assert np.all(np.abs(vis - ref) <= 3 * sigma + 2e-3), (vis - ref, sigma)
    if tilt == 0.0:  # zonal: only m = 0 survives
        m0 = [l * (l + 1) for l in range(ORDER)]
        others = np.setdiff1d(np.arange(ORDER * ORDER), m0)
        assert np.abs(vis[others]).max() < 0.01


def test_512_rays_converge_to_8192_within_mc_error(plane_mesh: trimesh.Trimesh) -> None:
    """SH from 512 rays matches SH from 8192 rays within the plain Monte Carlo error, over many vertices."""
    sphere = trimesh.creation.icosphere(subdivisions=3, radius=1.0)
    sphere.apply_translation((0.0, 0.0, 1.5))
    mesh = trimesh.util.concatenate([plane_mesh, sphere])
    scene = RayScene(mesh.vertices, mesh.faces)
    rng = np.random.default_rng(2)
    n = 64
    pts = np.c_[rng.uniform(-2, 2, (n, 2)), np.zeros(n)]
    frames = np.stack([frame_about_z(a) for a in rng.uniform(0, 2 * math.pi, n)])
    lo = trace_frame(pts, frames, None, RaySet.make(512, ORDER, n, seed=1), offset=1e-4, scene=scene).visibility
    hi = trace_frame(pts, frames, None, RaySet.make(8192, ORDER, n, seed=2), offset=1e-4, scene=scene).visibility
    # plain MC standard error of a 0/1 integrand, bounded by its worst case: 2 pi * max|y| * 0.5 / sqrt(R)
    ymax = np.abs(sh_basis(_unit(20000), ORDER)).max(axis=0)
    sigma = 2 * math.pi * ymax * 0.5 / math.sqrt(512)
    err = np.abs(lo - hi)
    assert np.all(err <= 4 * sigma)
    assert np.sqrt((err**2).mean()) <= sigma.mean()  # typical error well inside one sigma
    assert not np.allclose(lo, hi, atol=1e-6)  # the two estimates really are different samples


def _unit(n: int) -> np.ndarray:
    d = np.random.default_rng(3).normal(size=(n, 3))
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def test_rotate_sh_z_matches_direct_evaluation() -> None:
    """rotate_sh_z(f, phi) are the coefficients of f(Rz(phi)^T u): compare pointwise with sh_basis."""
    order = 6
    rng = np.random.default_rng(4)
    f = rng.normal(size=(5, order * order))
    phi = rng.uniform(0, 2 * math.pi, 5)
    g = rotate_sh_z(f, phi)
    u = _unit(50)
    for k in range(5):
        c, s = math.cos(phi[k]), math.sin(phi[k])
        rz = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])
        lhs = sh_basis(u, order) @ g[k]
        rhs = sh_basis(u @ rz, order) @ f[k]  # rows: (Rz^T u)^T = u^T Rz
        np.testing.assert_allclose(lhs, rhs, atol=1e-10)


def test_projection_of_rotated_set_equals_direct_quadrature() -> None:
    """Projecting per-vertex rotated rays then rotating back = quadrature of the function itself."""
    order = 5
    rays = RaySet.make(4096, order, 3, seed=9)
    axis = np.array([0.6, 0.0, 0.8])
    vals = []
    local = rays.local.astype(np.float64)
    local /= np.linalg.norm(local, axis=1, keepdims=True)
    for k in range(3):
        c, s = math.cos(rays.phi[k]), math.sin(rays.phi[k])
        d = local @ np.array([[c, s, 0], [-s, c, 0], [0, 0, 1.0]])  # Rz(phi) d_r
        vals.append((d @ axis > 0.9).astype(np.float32))
    got = project_visibility(np.stack(vals, axis=1), projection_table(local, order), rays.phi)
    ref = cap_sh(axis, 0.9, order)
    for k in range(3):
        np.testing.assert_allclose(got[k], ref, atol=0.03)


def test_bad_inputs_raise_prt_error(plane_mesh: trimesh.Trimesh) -> None:
    rays = RaySet.make(64, ORDER, 2, seed=0)
    pts = np.zeros((2, 3))
    frames = np.stack([np.eye(3)] * 2)
    scene = RayScene(plane_mesh.vertices, plane_mesh.faces)
    bad = pts.copy()
    bad[1, 0] = np.nan
    with pytest.raises(PrtError, match="NaN"):
        trace_frame(bad, frames, None, rays, offset=1e-4, scene=scene)
    with pytest.raises(PrtError, match="shape"):
        trace_frame(pts[:, :2], frames, None, rays, offset=1e-4, scene=scene)
    with pytest.raises(PrtError, match="vertices"):
        trace_frame(np.zeros((3, 3)), np.stack([np.eye(3)] * 3), None, rays, offset=1e-4, scene=scene)
    with pytest.raises(PrtError, match="NaN"):
        RayScene(np.full((3, 3), np.nan), np.array([[0, 1, 2]]))
    with pytest.raises(PrtError, match="faces"):
        RayScene(np.zeros((3, 3)), np.array([[0, 1, 5]]))

"""SHEXP visibility against independent references: quadrature of exact caps, Embree rays on real spheres,
the brute-force matrix exponential, ``sh.rotation``; containment rules; bad input."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from prt_torch.errors import PrtError
from prt_torch.sh.project import project
from prt_torch.sh.quadrature import sphere_directions, sphere_quadrature
from prt_torch.shexp import exp_reference, log_visibility_table, sh_exp, shexp_visibility

ORDER = 4


@pytest.fixture(scope="module")
def quad() -> tuple[np.ndarray, np.ndarray]:
    return sphere_quadrature(131)


def _unit(v: list[float]) -> np.ndarray:
    a = np.asarray(v, dtype=np.float64)
    return a / np.linalg.norm(a)


def _rel(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.linalg.norm(np.asarray(a, np.float64) - b) / np.linalg.norm(b))


# relative L2 tolerance of exp(tabulated log) vs the exact cap's projection, by angular radius (order 4).
# Measured: 0.1 % (10 deg), 0.6 % (30), 2.1 % (50), 5.0 % (70), 5.7 % (85): the log fit's own residual
# (ridge-limited, tables.py) plus HYB's error.
CAP_TOL = [(10, 0.005), (30, 0.015), (50, 0.04), (70, 0.08), (85, 0.09)]


@pytest.mark.parametrize("deg,tol", CAP_TOL)
def test_one_sphere_vs_quadrature_of_the_exact_cap(quad: tuple[np.ndarray, np.ndarray], deg: int, tol: float) -> None:
    d, w = quad
    u = _unit([0.3, -0.5, 0.8])
    a = math.radians(deg)
    dist = 2.0
    v = shexp_visibility(np.zeros((1, 3)), (dist * u)[None], np.array([dist * math.sin(a)]), ORDER).numpy()[0]
    exact = project((d @ u < math.cos(a)).astype(np.float64), d, w, ORDER)
    assert _rel(v, exact) < tol


def test_two_disjoint_spheres_vs_the_exact_product_of_caps(quad: tuple[np.ndarray, np.ndarray]) -> None:
    d, w = quad
    p = np.array([0.1, -0.2, 0.05])
    c = np.array([[1.6, 0.3, 0.4], [-0.5, 1.4, 1.1]])
    r = np.array([0.7, 0.5])
    v = shexp_visibility(p[None], c, r, ORDER).numpy()[0]
    vis = np.ones(d.shape[0])
    for ci, ri in zip(c, r, strict=True):
        u = (ci - p) / np.linalg.norm(ci - p)
        vis *= d @ u < math.sqrt(1 - (ri / np.linalg.norm(ci - p)) ** 2)
    exact = project(vis, d, w, ORDER)
    assert _rel(v, exact) < 0.03  # measured ~1 %


def test_two_spheres_vs_embree_rays_on_triangulated_spheres() -> None:
    trimesh = pytest.importorskip("trimesh")
    pytest.importorskip("embreex")
    from prt_torch.bake.embree import RayScene

    c = np.array([[1.2, -0.4, 0.9], [-0.3, 1.5, -0.2]])
    r = np.array([0.6, 0.45])
    parts = [trimesh.creation.icosphere(subdivisions=5, radius=ri) for ri in r]
    verts, faces, off = [], [], 0
    for m, ci in zip(parts, c, strict=True):
        verts.append(m.vertices + ci)
        faces.append(m.faces + off)
        off += len(m.vertices)
    scene = RayScene(np.concatenate(verts).astype(np.float32), np.concatenate(faces).astype(np.int64))
    pts = np.array([[0.0, 0.0, 0.0], [0.3, 0.2, -0.4]])
    dirs = sphere_directions(40000, seed=3)
    wts = np.full(dirs.shape[0], 4 * math.pi / dirs.shape[0])
    v = shexp_visibility(pts, c, r, ORDER).numpy()
    for i, p in enumerate(pts):
        occ = scene.occluded(np.repeat(p[None], dirs.shape[0], 0), dirs)
        truth = project((~occ).astype(np.float64), dirs, wts, ORDER)
        assert _rel(v[i], truth) < 0.03  # measured ~1 %: the exponential's error, rays add ~0.3 %


def _log_vectors(order: int, deg: float, n: int = 3, seed: int = 1) -> np.ndarray:
    from prt_torch.sh.zonal import zh_to_sh

    t = log_visibility_table(order)
    row = int(round(deg / 90 * (t.shape[0] - 1)))
    return zh_to_sh(np.repeat(t[row][None], n, 0), sphere_directions(n, seed=seed)).sum(0)


def test_exp_reference_is_the_matrix_exponential_of_the_product_operator() -> None:
    import scipy.linalg

    from prt_torch.sh.product import gaunt_tensor

    f = _log_vectors(3, 40)
    g = gaunt_tensor(3).dense()
    m = np.einsum("ijk,k->ij", g, f)
    one = np.zeros(9)
    one[0] = math.sqrt(4 * math.pi)
    series = one.copy()
    term = one.copy()
    for k in range(1, 60):  # the product series of Ren 2006: sum f^{*k} / k!
        term = m @ term / k
        series += term
    assert np.allclose(exp_reference(f), series, rtol=1e-9, atol=1e-12)
    assert np.allclose(exp_reference(f), scipy.linalg.expm(m) @ one)


@pytest.mark.parametrize("deg,tol_hyb,tol_ol", [(15, 0.01, 0.01), (35, 0.01, 0.15), (70, 0.06, 1.0)])
def test_hyb_and_ol_vs_brute_force_exponential(deg: float, tol_hyb: float, tol_ol: float) -> None:
    f = _log_vectors(ORDER, deg)
    ref = exp_reference(f)
    hyb = sh_exp(torch.from_numpy(f), "hyb").numpy()
    ol = sh_exp(torch.from_numpy(f), "ol").numpy()
    assert _rel(hyb, ref) < tol_hyb
    assert _rel(ol, ref) < tol_ol
    if deg >= 35:  # large magnitudes: scaling and squaring is what makes HYB accurate
        assert _rel(hyb, ref) < 0.5 * _rel(ol, ref)


def test_dc_isolation_is_exact() -> None:
    f = _log_vectors(ORDER, 30)
    g = f.copy()
    g[0] -= 1.3 * math.sqrt(4 * math.pi)  # exp(-1.3) times the same function
    for method in ("hyb", "ol"):
        a = sh_exp(torch.from_numpy(f), method).numpy()
        b = sh_exp(torch.from_numpy(g), method).numpy()
        assert np.allclose(b, a * math.exp(-1.3), rtol=1e-10)


def test_receiver_inside_a_sphere_ignores_it() -> None:
    c = np.array([[0.0, 0.0, 0.0], [2.0, 0.5, 0.3]])
    r = np.array([1.0, 0.6])
    pts = np.array([[0.2, 0.1, -0.3], [0.0, 0.0, 0.9]])  # both inside sphere 0
    both = shexp_visibility(pts, c, r, ORDER).numpy()
    only = shexp_visibility(pts, c[1:], r[1:], ORDER).numpy()
    assert np.allclose(both, only, atol=1e-6)


def test_receiver_inside_every_sphere_is_unoccluded() -> None:
    c = np.array([[0.0, 0.0, 0.0], [0.3, 0.0, 0.0], [0.0, -0.2, 0.1]])
    r = np.array([1.0, 1.1, 0.9])
    v = shexp_visibility(np.array([[0.05, 0.0, 0.0]]), c, r, ORDER).numpy()[0]
    want = np.zeros(ORDER * ORDER)
    want[0] = math.sqrt(4 * math.pi)
    assert np.allclose(v, want, atol=1e-6)


def test_local_frame_equals_rotating_the_world_sh_and_projecting_in_the_frame(quad: tuple[np.ndarray, np.ndarray]
                                                                             ) -> None:
    from prt_torch.sh.quadrature import random_rotations
    from prt_torch.sh.rotation import sh_rotation

    d, w = quad
    pts = np.array([[0.0, 0.0, 0.0], [0.4, -0.3, 0.2], [-0.5, 0.1, 0.6]])
    c = np.array([[1.5, 0.2, 0.7], [-0.4, 1.2, 1.0]])
    r = np.array([0.6, 0.4])
    frames = random_rotations(3, seed=4)  # rows t, b, n: local = F @ world
    world = shexp_visibility(pts, c, r, ORDER).numpy()
    local = shexp_visibility(pts, c, r, ORDER, frames=frames).numpy()
    rotated = np.einsum("vij,vj->vi", sh_rotation(frames, ORDER), world)
    assert np.allclose(local, rotated, atol=2e-5)
    # direct projection in the frame: the exact caps seen in local coordinates, one sphere
    f0 = frames[1]
    one = shexp_visibility(pts[1:2], c[:1], r[:1], ORDER, frames=f0[None]).numpy()[0]
    u = f0 @ (c[0] - pts[1])
    dist = np.linalg.norm(u)
    exact = project((d @ (u / dist) < math.sqrt(1 - (r[0] / dist) ** 2)).astype(float), d, w, ORDER)
    assert _rel(one, exact) < 0.03


def test_below_horizon_conventions_are_one_sh_product() -> None:
    from prt_torch.sh.product import sh_product
    from prt_torch.sh.zonal import hemisphere_zh, zh_to_sh

    pts = np.array([[0.0, 0.0, 0.0]])
    frames = np.eye(3)[None]
    c = np.array([[0.8, 0.3, 1.2]])
    r = np.array([0.5])
    v = shexp_visibility(pts, c, r, ORDER, frames=frames).numpy()[0].astype(np.float64)
    h = zh_to_sh(hemisphere_zh(ORDER), np.array([0.0, 0.0, 1.0]))
    one = np.zeros(ORDER * ORDER)
    one[0] = math.sqrt(4 * math.pi)
    zero = shexp_visibility(pts, c, r, ORDER, frames=frames, below_horizon="zero").numpy()[0]
    ones = shexp_visibility(pts, c, r, ORDER, frames=frames, below_horizon="one").numpy()[0]
    assert np.allclose(zero, sh_product(h, v), atol=1e-5)
    assert np.allclose(ones, one - sh_product(h, one - v), atol=1e-5)


def test_batched_and_chunked_equal_per_item(monkeypatch: pytest.MonkeyPatch) -> None:
    import prt_torch.shexp.visibility as vis

    rng = np.random.default_rng(0)
    pts = rng.normal(size=(2, 50, 3))
    c = rng.normal(size=(2, 6, 3)) * 2
    r = rng.uniform(0.2, 0.6, size=(2, 6))
    full = shexp_visibility(pts, c, r, 3).numpy()
    monkeypatch.setattr(vis, "CHUNK_ELEMENTS", 2 * 6 * 9 * 7)  # 7 vertices per chunk
    chunked = shexp_visibility(pts, c, r, 3).numpy()
    assert np.allclose(full, chunked, atol=1e-6)
    for b in range(2):
        assert np.allclose(full[b], shexp_visibility(pts[b], c[b], r[b], 3).numpy(), atol=1e-6)


@pytest.mark.parametrize("kwargs,match", [
    ({"points": np.array([[np.nan, 0.0, 0.0]])}, "NaN"),
    ({"points": np.zeros((4, 2))}, r"\(\.\.\., V, 3\)"),
    ({"radii": np.array([0.5, 0.2])}, "radii"),
    ({"radii": np.array([0.0])}, "> 0"),
    ({"order": 0}, "order"),
    ({"method": "taylor"}, "method"),
    ({"frames": np.eye(3)[None].repeat(2, 0)}, "frames"),
    ({"below_horizon": "zero"}, "frames"),
])
def test_bad_input_is_one_line(kwargs: dict, match: str) -> None:
    args = {"points": np.zeros((1, 3)), "centers": np.array([[2.0, 0.0, 0.0]]), "radii": np.array([0.5]),
            "order": 3} | kwargs
    with pytest.raises(PrtError, match=match) as e:
        shexp_visibility(**args)
    assert "\n" not in str(e.value)

"""Cone-sphere occlusion of peak lights (issue 27 items 2 and 6, ``spheres``) against independent references:

* the cap-intersection solid angle vs Monte-Carlo directions (overlap, containment both ways, disjoint, sun-sized);
* one sphere vs Embree rays to disc samples against a triangulated sphere (the oracle,
  :func:`prt_torch.bake.peaks.exact_peak_visibility`);
* the penumbra of a plane under a sphere vs a quadrature over the disc (scipy) and vs Embree on sphere + plane.

Tolerances: ``TOL_SIGMA`` binomial standard deviations of the sample count plus one sample (discreteness); against
a triangulated sphere, the answer for the polyhedron lies between those of its inscribed and circumscribed spheres
(visibility falls with the radius), so the Embree share must lie in that bracket within the sampling tolerance.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from prt_torch.bake.embree import RayScene
from prt_torch.bake.peaks import exact_peak_visibility
from prt_torch.blockers.cones import cap_intersection, cap_solid_angle, horizon_fraction, sphere_peak_visibility
from prt_torch.errors import PrtError

TOL_SIGMA = 5.0  # per estimate; with a few hundred estimates a test fails by chance with probability < 1e-4


def binomial_tol(p: np.ndarray, n: int) -> np.ndarray:
    """``TOL_SIGMA`` binomial standard deviations of a share ``p`` estimated from ``n`` samples, plus ``1 / n``."""
    p = np.clip(np.asarray(p, dtype=np.float64), 0, 1)
    return TOL_SIGMA * np.sqrt(p * (1 - p) / n) + 1.0 / n


def cap_configurations(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(a, b, gamma)``: 60 each of overlap, light inside occluder, occluder inside light, disjoint, and 40 lenses of
    a sun-sized light (0.265 deg)."""
    k = 60
    a = rng.uniform(0.02, 1.5, 4 * k)
    b = rng.uniform(0.02, 1.5, 4 * k)
    lo, hi = np.abs(a - b), a + b
    g = np.concatenate([
        rng.uniform(lo[:k], hi[:k]),                                  # lens
        np.zeros(k), np.zeros(k),                                     # containment, set below
        np.minimum(hi[3 * k:] + rng.uniform(0.0, 0.5, k), math.pi),   # disjoint
    ])
    a[k:2 * k], b[k:2 * k] = np.minimum(a[k:2 * k], b[k:2 * k]), np.maximum(a[k:2 * k], b[k:2 * k])  # light inside
    g[k:2 * k] = rng.uniform(0, 1, k) * (b[k:2 * k] - a[k:2 * k])
    a[2 * k:3 * k], b[2 * k:3 * k] = np.maximum(a[2 * k:3 * k], b[2 * k:3 * k]), np.minimum(a[2 * k:3 * k],
                                                                                             b[2 * k:3 * k])
    g[2 * k:3 * k] = rng.uniform(0, 1, k) * (a[2 * k:3 * k] - b[2 * k:3 * k])
    sun = np.full(40, math.radians(0.265))
    bs = rng.uniform(0.001, 1.2, 40)
    gs = rng.uniform(np.abs(sun - bs), sun + bs)
    return np.concatenate([a, sun]), np.concatenate([b, bs]), np.concatenate([g, gs])


def test_cap_intersection_vs_monte_carlo() -> None:
    rng = np.random.default_rng(7)
    a, b, g = cap_configurations(rng)
    n = 20000
    # uniform directions in cap a about +z (cos theta uniform in [cos a, 1]); inside cap b about (sin g, 0, cos g)
    one_minus_cos = rng.random((a.size, n)) * (2 * np.sin(a[:, None] / 2) ** 2)
    cos_t = 1 - one_minus_cos
    sin_t = np.sqrt(one_minus_cos * (2 - one_minus_cos))
    phi = rng.uniform(0, 2 * math.pi, (a.size, n))
    # angle to the occluder axis > b  <=>  cos(angle) < cos b, written without cancellation via 1 - cos
    cos_to_b = sin_t * np.cos(phi) * np.sin(g)[:, None] + cos_t * np.cos(g)[:, None]
    inside = cos_to_b > np.cos(b)[:, None]
    share = inside.mean(1)
    want = cap_intersection(a, b, g) / cap_solid_angle(a)
    assert np.all(np.abs(share - want) <= binomial_tol(want, n)), np.max(np.abs(share - want) / binomial_tol(want, n))
    assert np.all(want[:60] > 0) and np.all(want[60:120] == 1) and np.all(want[180:240] == 0)
    np.testing.assert_allclose(want[120:180], cap_solid_angle(b[120:180]) / cap_solid_angle(a[120:180]), rtol=1e-12)


def test_cap_intersection_is_symmetric_and_has_its_limits() -> None:
    rng = np.random.default_rng(1)
    a, b, g = cap_configurations(rng)
    np.testing.assert_allclose(cap_intersection(a, b, g), cap_intersection(b, a, g), rtol=1e-9, atol=1e-15)
    x = np.array([0.3, 0.0046])
    np.testing.assert_allclose(cap_intersection(x, x, 0 * x), cap_solid_angle(x), rtol=1e-12)  # identical caps
    half = np.full(2, math.pi / 2)
    np.testing.assert_allclose(cap_intersection(x, half, half), cap_solid_angle(x) / 2, rtol=1e-12)  # a great circle
    # continuous at both ends of the lens range
    for edge in (np.abs(a - b), a + b):
        np.testing.assert_allclose(cap_intersection(a, b, edge * (1 - 1e-9)), cap_intersection(a, b, edge * (1 + 1e-9)),
                                   atol=1e-6 * cap_solid_angle(np.minimum(a, b)).max())


def test_torch_float32_matches_numpy_float64() -> None:
    torch = pytest.importorskip("torch")
    rng = np.random.default_rng(2)
    pos = rng.normal(0, 0.3, (2, 400, 3))
    nrm = rng.normal(0, 1, (2, 400, 3))
    nrm /= np.linalg.norm(nrm, axis=-1, keepdims=True)
    cen = rng.normal(0, 0.3, (2, 12, 3))
    rad = rng.uniform(0.02, 0.1, 12)
    dirs = np.array([[0.0, 0.0, 1.0], [0.6, 0.0, 0.8]])
    radii = np.array([math.radians(0.265), math.radians(5.0)])
    ref = sphere_peak_visibility(pos, nrm, cen, rad, dirs, radii)
    assert ref.shape == (2, 400, 2) and ref.dtype == np.float64
    assert ((ref > 0) & (ref < 1)).sum() > 20  # penumbrae are exercised
    out = sphere_peak_visibility(*(torch.tensor(x, dtype=torch.float32) for x in (pos, nrm, cen, rad, dirs, radii)))
    assert isinstance(out, torch.Tensor) and out.dtype == torch.float32
    f32 = sphere_peak_visibility(*(x.astype(np.float32) for x in (pos, nrm, cen, rad, dirs, radii)))
    assert f32.dtype == np.float32
    # float32 geometry: angles to ~1e-7 rad relative to the scene, over a disc of 0.0046 rad: a few 1e-4 of the share
    tol = 50 * np.finfo(np.float32).eps / math.radians(0.265)
    np.testing.assert_allclose(out.numpy(), ref, atol=tol)
    np.testing.assert_allclose(f32, ref, atol=tol)
    # float64: torch's whole-array overlap test and numpy's compiled one find the same triples (to rounding)
    t64 = sphere_peak_visibility(*(torch.tensor(x, dtype=torch.float64) for x in (pos, nrm, cen, rad, dirs, radii)))
    np.testing.assert_allclose(t64.numpy(), ref, atol=1e-9)
    assert ((0 <= ref) & (ref <= 1)).all()


def icosphere(center: np.ndarray, radius: float) -> tuple[np.ndarray, np.ndarray, float]:
    """A triangulated sphere ``(vertices, faces)`` and its inscribed radius (the faces' least distance to the
    centre); its vertices lie on the sphere, so it lies between the spheres of these two radii."""
    import trimesh

    m = trimesh.creation.icosphere(subdivisions=5, radius=radius)
    tri = m.vertices[m.faces]
    nrm = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    inner = float(np.min(np.abs((nrm * tri[:, 0]).sum(1)) / np.linalg.norm(nrm, axis=1)))
    return m.vertices + center, np.asarray(m.faces), inner


def bracket(pos: np.ndarray, nrm: np.ndarray, center: np.ndarray, radius: float, inner: float, dirs: np.ndarray,
            radii: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The sphere kernel's answer for the circumscribed (lower) and inscribed (upper) sphere."""
    lo = sphere_peak_visibility(pos, nrm, center[None], np.array([radius]), dirs, radii)
    hi = sphere_peak_visibility(pos, nrm, center[None], np.array([inner]), dirs, radii)
    return lo, hi


def test_one_sphere_vs_embree_on_a_triangulated_sphere() -> None:
    rng = np.random.default_rng(3)
    center, radius = np.array([0.1, -0.2, 0.5]), 0.25
    verts, faces, inner = icosphere(center, radius)
    # receivers 0.5-2 from the sphere, lights of 2-15 degrees aimed so that the sphere's cap meets the disc
    n_recv = 150
    u = rng.normal(size=(n_recv, 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    dist = rng.uniform(0.5, 2.0, n_recv)
    pos = center - u * dist[:, None]
    b = np.arcsin(radius / dist)
    r = np.radians(rng.uniform(2, 15, n_recv))
    gamma = rng.uniform(np.maximum(np.abs(b - r) - r, 0), b + r)  # lenses, containment and a little disjoint
    perp = np.cross(u, rng.normal(size=(n_recv, 3)))
    perp /= np.linalg.norm(perp, axis=1, keepdims=True)
    light = np.cos(gamma)[:, None] * u + np.sin(gamma)[:, None] * perp
    side = 24
    got = np.empty(n_recv)
    lo = np.empty(n_recv)
    hi = np.empty(n_recv)
    scene = RayScene(verts, faces)
    for dirs, radii, sel in ((light[i:i + 1], r[i:i + 1], slice(i, i + 1)) for i in range(n_recv)):
        got[sel] = exact_peak_visibility(pos[sel], dirs, dirs, radii, 0.0, scene=scene, side=side)[:, 0]
        lo[sel], hi[sel] = (x[:, 0] for x in bracket(pos[sel], dirs, center, radius, inner, dirs, radii))
    tol = binomial_tol((lo + hi) / 2, side * side)
    assert np.all(got >= lo - tol) and np.all(got <= hi + tol)
    assert ((lo > 0.05) & (hi < 0.95)).sum() > 50  # mostly penumbrae


def penumbra_by_quadrature(x: np.ndarray, height: float, radius: float, light: np.ndarray, r: float) -> np.ndarray:
    """Visible share of a disc light at receivers ``(x, 0, 0)`` under the sphere ``((0, 0, height), radius)``, by
    quadrature over the disc's polar angle ``theta``: the ring of directions ``theta`` from the light meets the
    sphere's cap (half-angle ``beta``, ``gamma`` from the light) where ``cos phi > (cos beta - cos theta cos gamma)
    / (sin theta sin gamma)``, an arc of ``2 acos`` of that."""
    from scipy.integrate import quad

    out = np.empty(x.size)
    for i, xi in enumerate(x):  # a handful of reference points, one quadrature each
        c = np.array([-xi, 0.0, height])
        d = float(np.linalg.norm(c))
        beta = math.asin(radius / d)
        gamma = math.acos(float(np.clip(c @ light / d, -1, 1)))

        def hidden(theta: float, beta: float = beta, gamma: float = gamma) -> float:
            if gamma < 1e-12:
                return 2 * math.pi * math.sin(theta) if theta < beta else 0.0
            k = (math.cos(beta) - math.cos(theta) * math.cos(gamma)) / (math.sin(theta) * math.sin(gamma))
            return 2 * math.acos(min(1.0, max(-1.0, k))) * math.sin(theta)

        breaks = [t for t in (abs(gamma - beta), gamma + beta) if 0 < t < r]
        val, _ = quad(hidden, 1e-15, r, points=breaks or None, epsabs=1e-13, epsrel=1e-11, limit=200)
        out[i] = 1 - val / (2 * math.pi * (1 - math.cos(r)))
    return out


@pytest.mark.parametrize("tilt_deg, radius_deg", [(0.0, 3.0), (30.0, 8.0), (50.0, 0.265)])
def test_penumbra_of_a_plane_under_a_sphere(tilt_deg: float, radius_deg: float) -> None:
    height, radius = 1.0, 0.3
    t, r = math.radians(tilt_deg), math.radians(radius_deg)
    light = np.array([math.sin(t), 0.0, math.cos(t)])
    # a line through the shadow: the delta light's shadow edges are x = (-height sin t +- radius) / cos t (the ray
    # along the light passes the centre at the radius); receivers across them, the penumbra about
    # (height / cos t) tan r / cos t wide, and a few in the umbra and outside
    edges = (-height * math.sin(t) + np.array([-radius, radius])) / math.cos(t)
    width = 1.5 * height * math.tan(r) / math.cos(t) ** 2
    x = np.sort(np.concatenate([np.linspace(edges[0] - 2 * width, edges[1] + 2 * width, 9),
                                *(np.linspace(e - width, e + width, 16) for e in edges)]))
    pos = np.stack([x, np.zeros_like(x), np.zeros_like(x)], 1)
    up = np.tile([0.0, 0.0, 1.0], (x.size, 1))
    closed = sphere_peak_visibility(pos, up, np.array([[0.0, 0.0, height]]), np.array([radius]), light[None],
                                    np.array([r]))[:, 0]
    sel = slice(None, None, 4)
    quadrature = penumbra_by_quadrature(x[sel], height, radius, light, r)
    np.testing.assert_allclose(closed[sel], quadrature, atol=1e-8)
    assert closed.min() == 0 and closed.max() == 1 and ((closed > 0) & (closed < 1)).sum() >= 6
    # Embree on a triangulated sphere over a floor quad (the receivers lie on the floor)
    verts, faces, inner = icosphere(np.array([0.0, 0.0, height]), radius)
    floor = np.array([[-9, -9, 0], [9, -9, 0], [9, 9, 0], [-9, 9, 0]], dtype=np.float64)
    scene = RayScene(np.vstack([verts, floor]), np.vstack([faces, len(verts) + np.array([[0, 1, 2], [0, 2, 3]])]))
    side = 24
    got = exact_peak_visibility(pos, up, light[None], np.array([r]), 1e-4, scene=scene, side=side)[:, 0]
    lo, hi = (v[:, 0] for v in bracket(pos, up, np.array([0.0, 0.0, height]), radius, inner, light[None],
                                        np.array([r])))
    tol = binomial_tol((lo + hi) / 2, side * side)
    assert np.all(got >= lo - tol) and np.all(got <= hi + tol)


def test_horizon_and_receivers_inside_a_sphere() -> None:
    r = np.array([math.radians(10.0)])
    up = np.array([[0.0, 0.0, 1.0]])
    tilted = np.array([[1.0, 0.0, 0.0]])  # the light's disc is cut in half by this receiver's horizon
    pos = np.zeros((1, 3))
    far = np.array([[50.0, 50.0, -50.0]])
    for nrm, want in ((up, 1.0), (tilted, 0.5), (-up, 0.0)):
        got = sphere_peak_visibility(pos, nrm, far, np.array([0.1]), up, r)
        np.testing.assert_allclose(got, want, atol=1e-12)
        np.testing.assert_allclose(horizon_fraction(nrm, up, r), want, atol=1e-12)
    # a sphere containing the receiver is ignored; the same sphere from outside hides the light
    inside = sphere_peak_visibility(pos, up, np.array([[0.0, 0.0, 0.05]]), np.array([0.1]), up, r)
    outside = sphere_peak_visibility(pos, up, np.array([[0.0, 0.0, 0.5]]), np.array([0.1]), up, r)
    assert inside[0, 0] == 1 and outside[0, 0] == 0


def test_independent_spheres_multiply() -> None:
    """Two spheres hiding the two halves of a disc: each alone leaves the other half (the product rule then
    gives 1/4 where the union leaves 0, the documented over-estimate of the independent-occluder rule)."""
    r = np.array([0.1])
    up = np.array([[0.0, 0.0, 1.0]])
    pos = np.zeros((1, 3))
    # caps of half-angle 0.5 tangent to the light's axis from both sides (gamma = b): each hides ~half the disc
    cen = np.array([[math.sin(0.5), 0.0, math.cos(0.5)], [-math.sin(0.5), 0.0, math.cos(0.5)]]) * 10.0
    rad = np.full(2, 10.0 * math.sin(0.5))
    each = [sphere_peak_visibility(pos, up, cen[i:i + 1], rad[i:i + 1], up, r)[0, 0] for i in range(2)]
    both = sphere_peak_visibility(pos, up, cen, rad, up, r)[0, 0]
    np.testing.assert_allclose(both, each[0] * each[1], rtol=1e-12)
    assert 0.4 < each[0] < 0.6


def test_bad_input_is_one_line() -> None:
    p, n = np.zeros((2, 3)), np.tile([0.0, 0.0, 1.0], (2, 1))
    c, rad = np.ones((3, 3)), np.full(3, 0.1)
    d, r = np.array([[0.0, 0.0, 1.0]]), np.array([0.1])
    with pytest.raises(PrtError, match=r"sphere radii must have shape \(S,\)"):
        sphere_peak_visibility(p, n, c, rad[:2], d, r)
    with pytest.raises(PrtError, match=r"angular radii must be in \(0, pi/2\]"):
        sphere_peak_visibility(p, n, c, rad, d, np.array([2.0]))
    with pytest.raises(PrtError, match="sphere radii must be > 0"):
        sphere_peak_visibility(p, n, c, 0 * rad, d, r)
    with pytest.raises(PrtError, match="receiver positions contain NaN"):
        sphere_peak_visibility(p * np.nan, n, c, rad, d, r)

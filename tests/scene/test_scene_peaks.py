"""Peak lights in a scene (issue 27): the floor's peak shadow and the characters' shadows on each other.

* the penumbra of a floor under a sphere: the floor's peak visibility (:func:`prt_torch.scene.peaks.
  floor_peak_visibility`, both cone-sphere kernels) vs the closed form of the cap overlap of two cones (the umbra's
  and the penumbra's edges along a line through the shadow, the visible share at the shadow's centre) and vs
  Embree on a triangulated sphere (:func:`prt_torch.scene.peaks.floor_exact_peak_visibility`);
* the scene player's floor: its peak term vs an independent numpy computation (the truth path's FK + LBS, spheres
  posed by hand, the general kernel, Lambert by hand), the residual on the SH path (an unshadowed floor vertex gets
  the same radiance as with the whole lighting on the SH path: the sun is not counted twice);
* two characters: the second stands in the first one's sun shadow; where Embree (the first one's posed mesh as
  the only occluder) says a vertex of the second is occluded, its in-scene peak visibility and peak radiance drop.
"""

from __future__ import annotations

import math
import shutil
from pathlib import Path

import numpy as np
import pytest

from prt_torch.scene.peaks import (
    above_floor_share,
    floor_exact_peak_visibility,
    floor_peak_radiance,
    floor_peak_visibility,
    inside_capsules,
    others_peak_visibility,
)
from tests.blockers.test_cone_occlusion import binomial_tol, icosphere

pytest_plugins = ["tests.fixtures_peaks"]


def kernels() -> list:
    from prt_torch.player.scene import compiled_kernel

    return [None, compiled_kernel]


def closed_form_edges(height: float, radius: float, tilt: float, a: float) -> tuple[tuple[float, float],
                                                                                   tuple[float, float]]:
    """The umbra ``(x0, x1)`` and the penumbra's outer edges ``(x0, x1)`` on the floor line ``y = 0`` under the
    sphere ``((0, 0, height), radius)`` for a disc light of half-angle ``a`` about ``(sin t, 0, cos t)``.

    The disc's directions in the plane ``y = 0`` are ``w(th) = (sin th, 0, cos th)``, ``th in [t - a, t + a]``; the
    ray from ``(x, 0, 0)`` along ``w(th)`` passes the centre at distance ``|g(th)|``, ``g = h sin th + x cos th``,
    increasing in ``th`` there. Both caps (the disc's, the sphere's seen from the receiver) have their axes in that
    plane, so the disc is hidden whole iff both extreme directions hit (``g(t - a) >= -R`` and ``g(t + a) <= R``)
    and not at all iff ``[g(t - a), g(t + a)]`` misses ``[-R, R]``."""
    def x_at(g: float, th: float) -> float:  # g(th) = g  ->  x
        return (g - height * math.sin(th)) / math.cos(th)

    lo, hi = tilt - a, tilt + a
    umbra = (x_at(-radius, lo), x_at(radius, hi))
    penumbra = (x_at(-radius, hi), x_at(radius, lo))
    return umbra, penumbra


@pytest.mark.parametrize("tilt_deg, radius_deg", [(0.0, 3.0), (35.0, 0.265), (50.0, 6.0)])
@pytest.mark.parametrize("kernel", kernels(), ids=["numpy", "compiled"])
def test_floor_penumbra_vs_closed_form(tilt_deg: float, radius_deg: float, kernel) -> None:
    height, radius = 1.0, 0.3
    t, a = math.radians(tilt_deg), math.radians(radius_deg)
    light = np.array([[math.sin(t), 0.0, math.cos(t)]])
    (u0, u1), (p0, p1) = closed_form_edges(height, radius, t, a)
    assert p0 < u0 < u1 < p1
    w = min(u0 - p0, p1 - u1)  # the penumbra's width on each side
    eps = 0.02 * w
    x = np.concatenate([np.linspace(u0 + eps, u1 - eps, 7),                          # umbra
                        np.linspace(p0 + eps, u0 - eps, 9), np.linspace(u1 + eps, p1 - eps, 9),  # penumbrae
                        p0 - eps - np.geomspace(1e-3, 2.0, 5), p1 + eps + np.geomspace(1e-3, 2.0, 5)])  # lit
    pts = np.stack([x, np.zeros_like(x), np.zeros_like(x)], 1)
    v = floor_peak_visibility(pts, *[np.array([[0.0, 0.0, height]])] * 2, np.array([radius]), light, np.array([a]),
                              kernel=kernel)[:, 0]
    assert v.shape == (x.size,) and v.dtype == np.float32
    assert (v[:7] == 0).all()  # exactly: the kernel counts a full occlusion apart
    pen = v[7:25]
    assert np.all((pen > 0) & (pen < 1))
    assert (v[25:] == 1).all()  # exactly: no overlap, no horizon cut
    # across each penumbra the visible share rises monotonically outwards
    assert np.all(np.diff(v[7:16]) < 0) and np.all(np.diff(v[16:25]) > 0)


@pytest.mark.parametrize("tilt_deg", [0.0, 40.0])
@pytest.mark.parametrize("kernel", kernels(), ids=["numpy", "compiled"])
def test_floor_shadow_centre_of_a_small_sphere(tilt_deg: float, kernel) -> None:
    """A sphere smaller than the disc as seen from the floor (no umbra, an antumbra): at the shadow's centre, the
    point whose ray along the light passes the sphere's centre, the sphere's whole cap (half-angle ``b = asin(R cos t
    / h)``) lies inside the disc, and the share seen is ``1 - (1 - cos b) / (1 - cos a)``."""
    height, radius, a = 1.0, 0.05, math.radians(8.0)
    t = math.radians(tilt_deg)
    light = np.array([[math.sin(t), 0.0, math.cos(t)]])
    b = math.asin(radius * math.cos(t) / height)
    assert b < a
    centre = np.array([[-height * math.tan(t), 0.0, 0.0]])
    v = floor_peak_visibility(centre, *[np.array([[0.0, 0.0, height]])] * 2, np.array([radius]), light, np.array([a]),
                              kernel=kernel)[0, 0]
    assert v == pytest.approx(1 - (1 - math.cos(b)) / (1 - math.cos(a)), abs=2e-5)


def test_floor_penumbra_vs_embree_and_inside_a_sphere() -> None:
    height, radius = 0.6, 0.3
    t, a = math.radians(30.0), math.radians(5.0)
    light = np.array([[math.sin(t), 0.0, math.cos(t)]])
    (u0, u1), (p0, p1) = closed_form_edges(height, radius, t, a)
    x = np.linspace(p0 - 0.05, p1 + 0.05, 120)
    pts = np.stack([x, np.zeros_like(x), np.zeros_like(x)], 1)
    center = np.array([0.0, 0.0, height])
    verts, faces, inner = icosphere(center, radius)
    side = 16
    got = floor_exact_peak_visibility(pts, [(verts, faces)], light, np.array([a]), 1e-4, side=side)[:, 0]
    lo = floor_peak_visibility(pts, center[None], center[None], np.array([radius]), light, np.array([a]))[:, 0]
    hi = floor_peak_visibility(pts, center[None], center[None], np.array([inner]), light, np.array([a]))[:, 0]
    tol = binomial_tol((lo + hi) / 2, side * side)
    assert np.all(got >= lo - tol) and np.all(got <= hi + tol)
    assert ((got > 0.05) & (got < 0.95)).sum() >= 15  # the penumbrae are sampled
    # a sphere crossing the floor: floor points inside it (under a "foot") are in its shadow, Embree agrees
    low = np.array([0.0, 0.0, 0.1])
    verts, faces, _ = icosphere(low, radius)
    under = np.array([[0.05, 0.02, 0.0], [-0.1, 0.1, 0.0]])
    assert inside_capsules(under, low[None], low[None], np.array([radius])).all()
    v = floor_peak_visibility(under, low[None], low[None], np.array([radius]), light, np.array([a]))
    assert (v == 0).all()
    assert (floor_exact_peak_visibility(under, [(verts, faces)], light, np.array([a]), 1e-4) == 0).all()


def test_floor_under_a_capsule_vs_embree_and_inside_it() -> None:
    """A lying capsule (a forearm over the floor) through the scene's floor rule vs Embree rays against the
    triangulated capsule; floor points under a capsule that crosses the floor are inside it and in its shadow."""
    from tests.blockers.test_capsules import capsule_mesh

    a_end, b_end, radius = np.array([-0.3, 0.0, 0.5]), np.array([0.3, 0.1, 0.55]), 0.12
    t, ang = math.radians(25.0), math.radians(4.0)
    light = np.array([[0.0, math.sin(t), math.cos(t)]])
    gx, gy = np.meshgrid(np.linspace(-0.6, 0.6, 25), np.linspace(-0.6, 0.4, 21))
    pts = np.stack([gx.ravel(), gy.ravel(), np.zeros(gx.size)], 1)
    verts, faces, inner = capsule_mesh(a_end, b_end, radius)
    side = 16
    got = floor_exact_peak_visibility(pts, [(verts, faces)], light, np.array([ang]), 1e-4, side=side)[:, 0]
    # the mesh lies between the capsules of its inscribed and its outer radius: Embree between their shadows, up to
    # the rays' binomial noise and the kernel's nearest-sphere penumbra (a 4-degree disc: a few percent at most)
    lo = floor_peak_visibility(pts, a_end[None], b_end[None], np.array([radius]), light, np.array([ang]))[:, 0]
    hi = floor_peak_visibility(pts, a_end[None], b_end[None], np.array([inner]), light, np.array([ang]))[:, 0]
    assert ((lo > 0.05) & (lo < 0.95)).sum() >= 10 and (lo == 0).sum() >= 10  # penumbra and umbra on the grid
    tol = binomial_tol((lo + hi) / 2, side * side) + 0.03
    assert np.all(got >= lo - tol) and np.all(got <= hi + tol)
    low_a, low_b = np.array([-0.2, 0.0, 0.05]), np.array([0.2, 0.0, 0.05])
    under = np.array([[0.15, 0.02, 0.0], [-0.1, -0.05, 0.0], [0.0, 0.0, 0.0]])
    assert inside_capsules(under, low_a[None], low_b[None], np.array([0.1])).all()
    assert not inside_capsules(np.array([[0.35, 0.0, 0.0]]), low_a[None], low_b[None], np.array([0.1])).any()
    assert (floor_peak_visibility(under, low_a[None], low_b[None], np.array([0.1]), light, np.array([ang])) == 0).all()


def test_floor_shading_and_floor_share_in_closed_form() -> None:
    d = np.array([[0.0, 0.6, 0.8], [0.0, 0.0, -1.0]])
    e = np.array([[2.0, 3.0, 4.0], [5.0, 5.0, 5.0]])
    vis = np.array([[1.0, 1.0], [0.25, 1.0]])
    alb = np.array([0.5, 0.6, 0.7])
    out = floor_peak_radiance(alb, d, e, vis)
    np.testing.assert_allclose(out, [alb / math.pi * e[0] * 0.8, alb / math.pi * e[0] * 0.8 * 0.25], rtol=1e-6)
    # the share of a disc above the horizontal: 1, 0, and a disc centred on the horizon: half
    share = above_floor_share(np.array([[0.0, 0.0, 1.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]]), np.full(3, 0.1))
    np.testing.assert_allclose(share, [1.0, 0.0, 0.5], atol=1e-6)
    # others' occlusion has no horizon share: a receiver whose normal faces away still sees an unblocked disc whole
    pos = np.zeros((1, 2, 3), np.float32)
    got = others_peak_visibility(pos, np.zeros((1, 0, 3)), np.zeros((1, 0, 3)), np.zeros(0), d[:1], np.array([0.1]))
    assert (got == 1).all()


# -- the scene player ------------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def peak_scene_run(peak_run: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A copy of ``peak_run`` with its sphere blockers and SHEXP graph (shipped when the export did not write
    them): a scene needs them."""
    from prt_torch.rundir import RunDir

    dst = tmp_path_factory.mktemp("peak_scene") / "run"
    shutil.copytree(peak_run, dst)
    run = RunDir(dst)
    if not (run.shexp_path.is_file() and run.blockers_path.is_file()):
        from prt_torch.shexp.graph import ship_shexp

        ship_shexp(run, run.character(), int(run.export_meta()["sh_order"]), 24)
    return dst


def posed_spheres_by_hand(spheres, skin: np.ndarray) -> np.ndarray:
    """``(S, 3)`` sphere centres carried by their bones: ``skin[bone] @ (c, 1)`` (one frame)."""
    c = np.concatenate([spheres.center, np.ones((len(spheres.center), 1))], axis=1)
    return np.einsum("sij,sj->si", skin[spheres.bone], c)[:, :3]


def test_scene_floor_peak_term_vs_numpy(peak_scene_run: Path) -> None:
    from prt_torch.blockers.cones import sphere_peak_visibility
    from prt_torch.player.scene import ScenePlayer
    from prt_torch.scene.config import scene_from_dict
    from prt_torch.scene.scene import pose_actor

    scene = scene_from_dict({"ground": {"resolution": 24}, "characters": [{"clip": "wave"}]})
    sp = ScenePlayer(peak_scene_run, scene=scene, window_size=(60, 80))
    sp0 = ScenePlayer(peak_scene_run, scene=scene, window_size=(60, 80), peaks=0)
    try:
        assert sp.n_peaks == 1 and sp.peak_kind == "learned" and sp0.n_peaks == 0
        frame = 3
        f = sp.compute(frame)
        g = sp.ground
        a = sp.actors[0]
        posed = pose_actor(a, a.locals(np.array([frame]), sp.fps))
        np.testing.assert_allclose(f.states[0].positions_vx3(0), posed.positions[0], atol=1e-4)
        pk = sp.primary.peaks
        c = posed_spheres_by_hand(sp.peak_blockers[0], posed.skin[0])
        up = np.tile([0.0, 0.0, 1.0], (g.n_vertices, 1))
        v = sphere_peak_visibility(g.vertices.astype(np.float64), up, c, sp.peak_blockers[0].radius.astype(np.float64),
                                   pk.directions, pk.angular_radii)
        d2 = ((g.vertices[:, None, :] - c[None]) ** 2).sum(-1)
        v[(d2 < sp.peak_blockers[0].radius[None] ** 2).any(1)] = 0.0
        np.testing.assert_allclose(f.ground_peak_visibility, v, atol=2e-4)
        assert (v < 0.5).sum() >= 3  # the character's shadow is on the floor
        term = (g.albedo / math.pi)[None] * ((v * np.maximum(pk.directions[:, 2], 0)) @ pk.powers)
        np.testing.assert_allclose(f.ground_radiance - sp.shade_ground(f.ground_visibility), term, rtol=1e-4,
                                   atol=1e-5 * float(term.max()))
        # the residual goes through the SH path; where nothing shadows the floor, residual + sun = the whole light:
        # the irradiance of the procedural sky by quadrature (its radiance function, the sun apart) + E cos
        from prt_torch.compare.reference import sky_radiance
        from prt_torch.sh.quadrature import hemisphere_directions

        assert "without" in sp.primary.lighting.source
        w = hemisphere_directions(100_000, seed=1)
        irradiance = (sky_radiance()(w) * w[:, 2:3]).mean(0) * 2 * math.pi + pk.powers[0] * pk.directions[0, 2]
        lit = (v[:, 0] == 1) & (f.ground_visibility[:, 0] > 0.999 * f.ground_visibility[:, 0].max())
        assert lit.sum() > 50
        np.testing.assert_allclose(f.ground_radiance[lit] * math.pi / g.albedo, np.broadcast_to(irradiance,
                                   (lit.sum(), 3)), rtol=0.03)  # the sun counted once (the window's residual bias)
        f0 = sp0.compute(frame)
        assert f0.ground_peak_visibility is None and f0.peak_visibility is None
        # the character's peak radiance: its own visibility times the floor's share (1 for the sun), Player's shading
        st = f.states[0]
        np.testing.assert_allclose(f.peak_visibility[0], sp.primary.peak_visibility(st), atol=1e-6)
    finally:
        sp.close()
        sp0.close()


def test_a_character_shadows_another(peak_scene_run: Path) -> None:
    from prt_torch.bake.embree import RayScene
    from prt_torch.bake.peaks import exact_peak_visibility
    from prt_torch.blockers.cones import horizon_fraction
    from prt_torch.player.scene import ScenePlayer
    from prt_torch.scene.config import scene_from_dict

    probe = ScenePlayer(peak_scene_run, scene=scene_from_dict({"characters": [{"clip": "wave"}]}),
                        window_size=(60, 80))
    try:
        sun = probe.primary.peaks.directions[0]
        rest = probe.actors[0].rest_vertices()
    finally:
        probe.close()
    height = float(np.ptp(rest[:, 2]))
    away = -sun[:2] / np.linalg.norm(sun[:2])  # the shadow falls this way
    offset = [*(0.55 * height * away), 0.0]
    scene = scene_from_dict({"ground": {"resolution": 8}, "characters": [
        {"clip": "wave"}, {"clip": "wave", "offset": offset, "time_offset": 0.2}]})
    sp = ScenePlayer(peak_scene_run, scene=scene, window_size=(60, 80))
    try:
        f = sp.compute(2)
        st0, st1 = f.states
        own = sp.actor_players[1].peak_visibility(st1)[0]  # (V, P): its own blockers only
        scene_v = f.peak_visibility[1][0]
        # Embree: the first character's posed mesh is the only occluder of the second's vertices
        pk = sp.primary.peaks
        mesh0 = RayScene(st0.positions_vx3(0), np.asarray(sp.actors[0].character.faces))
        p1 = st1.positions_vx3(0).astype(np.float64)
        n1 = np.ascontiguousarray(st1.normals[0].T, dtype=np.float64)
        ex = exact_peak_visibility(p1, n1, pk.directions, pk.angular_radii, 1e-4, scene=mesh0, side=4)[:, 0]
        horizon = horizon_fraction(n1, pk.directions, pk.angular_radii)[:, 0]
        shadowed = (horizon == 1) & (ex == 0) & (own[:, 0] > 0.9)
        clear = (horizon == 1) & (ex == 1) & (own[:, 0] > 0.9)
        assert shadowed.sum() >= 20 and clear.sum() >= 20
        ratio = scene_v[:, 0] / np.maximum(own[:, 0], 1e-6)
        # darkened where Embree says the first character is in the way: most of it (the fixture's learned blockers,
        # 64 spheres after 60 fit steps on a 2.9k-vertex character, cover ~80 % of the mesh's shadow here)
        assert np.mean(ratio[shadowed] < 0.5) > 0.7
        assert np.mean(ratio[clear] > 0.95) > 0.9  # and left alone where it is not
        # the peak term follows: Player.shade_peaks of the in-scene visibility, darker on the shadowed vertices
        p = sp.actor_players[1]
        term_scene = p.shade_peaks(st1, f.peak_visibility[1])[0].sum(-1)
        term_own = p.shade_peaks(st1, own[None])[0].sum(-1)
        lit = shadowed & (term_own > 0)
        assert lit.sum() >= 10 and term_scene[lit].sum() < 0.35 * term_own[lit].sum()
        assert term_scene[clear].sum() > 0.95 * term_own[clear].sum()
        resid = f.radiance[1][0] - p.shade_peaks(st1, f.peak_visibility[1])[0]
        np.testing.assert_allclose(resid, p.shade(st1, visibility=f.visibility[1], checked=False)[0], atol=1e-5)
    finally:
        sp.close()

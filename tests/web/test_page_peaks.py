"""The page with peak lights (issue 27 item 3): the site ships the sky's split and a peak-visibility graph, the
shader's peak term equals :func:`prt_torch.brdf.direct.peak_radiance` with the analytic BRDFs, the whole per-vertex
radiance (residual RPO shading + peaks) equals the Python computation (:func:`prt_torch.web.peaks.page_radiance`),
onnxruntime-web's peak visibility equals onnxruntime's, and the peaks toggle switches back to the whole lighting.

The tiny run has no learned peak blockers: its site's ``peaks.onnx`` is its blocker spheres' graph (the Python
player's fallback, :func:`prt_torch.web.site.write_peak_graph`), the same kernel as a learned one.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest

from prt_torch.scoring.statistics import image_psnr
from tests.tolerance import two_path_atol

SKY = {"light": "sky", "camera": "fixed", "playing": False, "unshadowed": False, "perPixel": False}
#: roundings along the longest chain of the page's float32 peak term: the local directions (3-term dots of float32
#: frames and a float32 view from eye - position, normalised), the BRDF (GLSL ES 3.00: exp2 / log2 3 ULP each, pow
#: inherited from them, so its relative error is the exponent times log2's) and the sum over peaks
PEAK_ROUNDINGS = 64
#: roundings of the SH path along its longest chain: W_b (NC terms) accumulated into u over NTERMS terms, one Gaunt
#: product output (a sum over its non-zeros, about 22 at order 4) and the NC-term dot per colour: 256 at order 4 and
#: 8 terms
SH_ROUNDINGS = 256


@pytest.fixture(scope="module")
def manifest(checked_site: tuple[Path, dict[str, Any]]) -> dict[str, Any]:
    from prt_torch.web.site import read_manifest

    return read_manifest(checked_site[0])


@pytest.fixture(scope="module")
def peak_graph(checked_site: tuple[Path, dict[str, Any]]):
    from prt_torch.web.peaks import PeakGraph
    from prt_torch.web.site import ASSETS, PEAKS_MODEL

    return PeakGraph(checked_site[0] / ASSETS / PEAKS_MODEL)


@pytest.fixture
def sky(player: Any):
    """``(whole sky Lighting, its PeakLighting)``; the shared player's lighting restored afterwards."""
    from prt_torch.player.peaks import load_peak_lighting

    whole = player.lighting
    yield whole, load_peak_lighting(None, player.order, "auto")
    player.lighting = whole
    player.light_angle = 0.0
    player.rotate_light(0.0)


def _flat_inputs(player: Any, state: Any, vis: np.ndarray, peak_vis: np.ndarray) -> dict[str, list[float]]:
    """The page's per-vertex inputs (window.prt.radiance) from a Python-posed batch of one."""
    n_v = state.positions.shape[2]
    pv = np.zeros((n_v, 4), np.float32)
    pv[:, :peak_vis.shape[-1]] = peak_vis.reshape(n_v, -1)
    return {"positions": state.positions[0].T.reshape(-1).astype(float).tolist(),
            "frames": state.frames_vx33()[0].reshape(-1).astype(float).tolist(),
            "visibility": np.asarray(vis, np.float32).reshape(-1).astype(float).tolist(),
            "peakVisibility": pv.reshape(-1).astype(float).tolist()}


def _page_radiance(page: Any, state: dict[str, Any], inputs: dict[str, list[float]] | None = None) -> np.ndarray:
    page.page.evaluate("s => window.prt.setState(s)", state)
    return np.reshape(page.page.evaluate("x => window.prt.radiance(x)", inputs), (-1, 3))


def _grazing(state: Any, eps: float = 1e-4) -> np.ndarray:
    """``(V,)`` vertices seen within ``eps`` of their horizon, where float32 and float64 may cut differently."""
    n = state.normals[0].T.astype(np.float64)
    v = state.view_dirs[0].T.astype(np.float64)
    return np.abs((n * v).sum(-1)) < eps


def test_site_ships_the_split_and_a_peak_graph(manifest: dict[str, Any], checked_site: tuple[Path, dict[str, Any]],
                                                player: Any) -> None:
    from prt_torch.brdf.rpo import builtin_brdf
    from prt_torch.player.peaks import load_peak_lighting
    from prt_torch.rig.material import character_material, material_brdf

    sky = load_peak_lighting(None, player.order, "auto")
    pk = manifest["lights"][0]["peaks"]
    assert len(pk["directions"]) == len(sky.peaks) == 1  # the sky's sun, by construction
    np.testing.assert_allclose(pk["directions"], sky.directions, rtol=0, atol=1e-7)
    np.testing.assert_allclose(pk["powers"], sky.powers, rtol=1e-7)
    np.testing.assert_allclose(pk["angular_radii"], sky.angular_radii, rtol=1e-7)
    np.testing.assert_allclose(pk["coeffs"], sky.lighting.coeffs, rtol=1e-6, atol=1e-7)  # the residual's lobes
    assert pk["tonemap"]["exposure"] > 0 and manifest["max_peaks"] == 4
    assert manifest["peaks_model"]["source"] == "spheres"  # the tiny run has no learned blockers
    assert (checked_site[0] / "assets" / manifest["peaks_model"]["file"]).stat().st_size == \
        manifest["peaks_model"]["bytes"]
    for r in manifest["rpos"]:
        b = material_brdf(character_material(player.character)) if r["name"] == "material" else builtin_brdf(r["name"])
        assert r["brdf"]["class"] == type(b).__name__
        assert r["brdf"]["params"][:2] == ([1.0, 0.0] if r["name"] == "lambert" else [b.kd, b.ks])


def test_shader_peak_term_equals_the_analytic_brdfs(page: Any, player: Any, manifest: dict[str, Any],
                                                    sky: Any) -> None:
    """SH visibility 0 (the SH path is linear in it: exactly 0), given peak visibility in [0, 1]: the page's
    radiance is its peak term alone, for every BRDF of the catalogue, light turned."""
    from prt_torch.rig.material import analytic_brdf, character_material
    from prt_torch.web.peaks import page_peak_radiance
    from prt_torch.web.site import site_local

    _, split = sky
    angle = 1.1
    state = player.pose(site_local(player.character, "wave", 4))
    rng = np.random.default_rng(0)
    n_v = state.positions.shape[2]
    pvis = rng.uniform(0.0, 1.0, (1, n_v, 1)).astype(np.float32)
    zero = np.zeros((n_v, player.order ** 2), np.float32)
    grazing = _grazing(state)
    turned = split.rotated_about_z(angle)
    for r in manifest["rpos"]:
        brdf = analytic_brdf(r["name"], character_material(player.character))
        want = page_peak_radiance(state, turned, pvis, brdf)[0]
        got = _page_radiance(page, {**SKY, "brdf": r["name"], "peaks": True, "lightAngle": angle},
                             _flat_inputs(player, state, zero, pvis))
        assert (want.max(-1) > 1e-3).sum() > n_v // 10, r["name"]  # the sun lights a good part of the body
        atol = two_path_atol(PEAK_ROUNDINGS, float(np.abs(want).max()))
        err = np.abs(got - want)[~grazing]
        assert err.max() <= atol, (r["name"], err.max(), atol)


def test_page_radiance_with_peaks_equals_python(page: Any, player: Any, peak_graph: Any, sky: Any) -> None:
    """The same posed inputs (Python's posing, the model's visibility, peaks.onnx in onnxruntime): the page's
    per-vertex radiance with peaks on (residual lobes + peak term) and off (the whole sky) equals Python's."""
    from prt_torch.rig.material import analytic_brdf
    from prt_torch.web.peaks import page_radiance
    from prt_torch.web.site import site_local

    whole, split = sky
    local = site_local(player.character, "squat", 5)
    for brdf, angle in (("phong", 0.4), ("lambert", 2.5)):
        player.set_brdf(brdf)
        for peaks in (True, False):
            state, want, pvis = page_radiance(player, local, whole, split if peaks else None, angle, peak_graph,
                                              analytic_brdf(brdf))
            vis = player.visibility(state.features)[0]
            pv = pvis if pvis is not None else np.ones((1, state.positions.shape[2], 1), np.float32)
            got = _page_radiance(page, {**SKY, "brdf": brdf, "peaks": peaks, "lightAngle": angle},
                                 _flat_inputs(player, state, vis, pv))
            want = want[0]
            atol = two_path_atol(SH_ROUNDINGS, float(np.abs(want).max()))
            err = np.abs(got - want)[~_grazing(state)]
            assert err.max() <= atol, (brdf, peaks, err.max(), atol)
            if peaks:
                assert (pvis < 0.5).any() and (pvis > 0.5).any(), "the sun neither shadows nor lights the body"


def test_onnxruntime_web_peak_visibility_equals_onnxruntime(page: Any, player: Any, peak_graph: Any) -> None:
    from prt_torch.export.peaks_graph import PARITY_RTOL, example_peaks
    from prt_torch.web.site import site_local

    ch = player.character
    local = np.concatenate([site_local(ch, c, f) for c, f in (("walk", 2), ("stretch", 6))])
    state = player.pose(local)
    dirs, radii = example_peaks(3, 2.0, seed=1)
    pos = np.ascontiguousarray(state.positions.transpose(0, 2, 1), np.float32)
    nrm = np.ascontiguousarray(state.normals.transpose(0, 2, 1), np.float32)
    skin = state.skin.astype(np.float32)
    want = peak_graph(pos, nrm, skin, dirs, radii)
    got = np.reshape(page.page.evaluate("a => window.prt.peakVisibility(a)", {
        "positions": pos.reshape(-1).astype(float).tolist(), "normals": nrm.reshape(-1).astype(float).tolist(),
        "skin": skin.reshape(-1).astype(float).tolist(), "directions": dirs.reshape(-1).astype(float).tolist(),
        "angular_radii": radii.astype(float).tolist(), "batch": 2}), want.shape)
    assert 0.01 < float((want < 0.99).mean()) < 0.99, "the discs are neither all seen nor all hidden"
    # the same float32 graph in two runtimes, against the module in float64: they agree to 1e-5 except where the
    # float32 kernel itself is ill-conditioned (acos / sqrt near tangency: native onnxruntime is as far from float64)
    import torch

    from prt_torch.blockers.spheres import SphereSet
    from prt_torch.models.peak_blockers import PeakBlockers

    module = PeakBlockers(SphereSet.load(player.bundle.run.blockers_path)).double().eval()
    with torch.no_grad():
        exact = module(*[torch.from_numpy(np.asarray(a, np.float64)) for a in (pos, nrm, skin, dirs, radii)]).numpy()
    assert np.abs(want - exact).max() <= PARITY_RTOL * 10
    assert np.linalg.norm(got - want) <= 1e-5 * np.linalg.norm(want)
    assert (np.abs(got - want) <= 1e-5 + 2 * np.abs(want - exact)).all()


def test_page_with_peaks_equals_python_on_its_own_posing(page: Any, player: Any, peak_graph: Any, sky: Any,
                                                        manifest: dict[str, Any]) -> None:
    """The whole page path (JS posing, onnxruntime-web visibility and peak graph, the shader) against Python's:
    per-vertex radiance and the frame; the peaks' shadow makes the frame differ from the whole sky's."""
    from prt_torch.player.tonemap import ToneMap
    from prt_torch.rig.material import analytic_brdf
    from prt_torch.web.peaks import page_radiance
    from prt_torch.web.site import site_local

    whole, split = sky
    tm_entry = manifest["lights"][0]["peaks"]["tonemap"]
    tm = {"exposure": tm_entry["exposure"], "white": tm_entry["white"]}
    angle = 2.0  # the sun from the character's side: its arms and legs shadow it
    player.set_brdf("phong")
    state, want, pvis = page_radiance(player, site_local(player.character, "wave", 6), whole, split, angle,
                                      peak_graph, analytic_brdf("phong"))
    base = {**SKY, "clip": "wave", "frame": 6, "brdf": "phong", "lightAngle": angle, "tonemap": tm}
    img, _ = page.frame({**base, "peaks": True})
    got = _page_radiance(page, {}, None)
    keep = ~_grazing(state, 1e-2)
    rel = np.linalg.norm((got - want[0])[keep]) / np.linalg.norm(want[0][keep])
    assert rel <= 2e-3, rel  # JS vs numpy posing (frames within 2e-4), the rest float32
    saved = player.exposure
    try:
        player.exposure = ToneMap(tm["exposure"], tm["white"])
        ref = player.render_frame(state, want)
    finally:
        player.exposure = saved
    from prt_torch.scoring.images import ImageRenderer, player_camera

    ch = player.character
    with ImageRenderer(ch.rest_vertices, ch.faces, player_camera(ch, (480, 640))) as r:
        mask = r.mask(state.positions_vx3(0))
    assert image_psnr(img, ref, mask) >= 35.0
    off, _ = page.frame({**base, "peaks": False})
    assert image_psnr(img, off, mask) < 35.0, "the peaks changed nothing"
    assert page.errors == []


def test_peaks_toggle_in_the_ui(page: Any) -> None:
    page.frame({**SKY, "clip": "walk", "frame": 0, "brdf": "lambert", "lightAngle": 0.0, "peaks": True})
    get = "() => ({on: window.prt.app.peaksOn, box: document.getElementById('peaks').checked, " \
          "hidden: document.getElementById('peaksRow').hidden, n: window.prt.app.material.uniforms.u_nPeaks.value, " \
          "dc: window.prt.app.m.lights[0].dirs.reduce((a, d, k) => a + " \
          "window.prt.app.material.uniforms.u_lobeG.value[k * window.prt.app.m.order].x, 0)})"
    on = page.page.evaluate(get)
    assert on == {**on, "on": True, "box": True, "hidden": False, "n": 1}
    page.page.click("#peaks")
    off = page.page.evaluate(get)
    assert off["on"] is False and off["box"] is False and off["n"] == 0
    assert off["dc"] > on["dc"]  # the SH path's mean radiance: the whole sky's has the sun's power in it
    page.page.keyboard.press("p")
    assert page.page.evaluate(get) == on
    page.page.evaluate("s => window.prt.setState(s)", {"playing": False, "paused": True})


def test_learned_peak_graph_runs_in_the_page(peak_run: Path, browser: Any, tmp_path: Path) -> None:
    """A run trained with ``train.peaks`` (order 3): the site ships its ``peaks.onnx`` byte for byte, onnxruntime-web
    runs it as onnxruntime does, and the page's radiance with peaks on equals Python's on the page's own posing."""
    from prt_torch.player.lighting import load_lighting
    from prt_torch.player.peaks import load_peak_lighting
    from prt_torch.player.player import Player
    from prt_torch.rig.material import analytic_brdf
    from prt_torch.rundir import RunDir
    from prt_torch.web.check import served_page
    from prt_torch.web.peaks import PeakGraph, page_radiance
    from prt_torch.web.site import ASSETS, read_manifest, site_local, write_site

    site = tmp_path / "site"
    write_site(peak_run, site, material_rpo=False, env_presets=False)
    m = read_manifest(site)
    assert m["peaks_model"]["source"] == "learned" and m["order"] == 3
    raw = (site / ASSETS / m["peaks_model"]["file"]).read_bytes()
    assert raw == RunDir(peak_run).peak_graph_path.read_bytes()
    graph = PeakGraph(site / ASSETS / m["peaks_model"]["file"])
    player = Player(peak_run, threads=1, graph="split")
    try:
        brdf = m["default_brdf"]
        player.set_brdf(brdf)
        whole, split = load_lighting(None, player.order), load_peak_lighting(None, player.order, "auto")
        local = site_local(player.character, "wave", 3)
        state, want, pvis = page_radiance(player, local, whole, split, 1.5, graph, analytic_brdf(brdf))
        with served_page(site, browser=browser) as ps:
            assert ps.wait_ready(), ps.page.evaluate("window.prt.error")
            ps.frame({**SKY, "clip": "wave", "frame": 3, "brdf": brdf, "lightAngle": 1.5, "peaks": True})
            got = _page_radiance(ps, {}, None)
            pos = state.positions[0].T.astype(np.float32)
            web_vis = np.reshape(ps.page.evaluate("a => window.prt.peakVisibility(a)", {
                "positions": pos.reshape(-1).astype(float).tolist(),
                "normals": state.normals[0].T.reshape(-1).astype(float).tolist(),
                "skin": state.skin.astype(np.float32).reshape(-1).astype(float).tolist(),
                "directions": split.rotated_about_z(1.5).directions.reshape(-1).astype(float).tolist(),
                "angular_radii": split.angular_radii.astype(float).tolist()}), pvis.shape)
            assert ps.errors == []
    finally:
        player.close()
    assert (pvis < 0.5).any(), "the learned blockers cast no sun shadow"
    assert np.linalg.norm(web_vis - pvis) <= 1e-5 * np.linalg.norm(pvis)
    keep = ~_grazing(state, 1e-2)
    rel = np.linalg.norm((got - want[0])[keep]) / np.linalg.norm(want[0][keep])
    assert rel <= 2e-3, rel  # JS vs numpy posing, as above

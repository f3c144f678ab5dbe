"""The three.js module (web/src/prt-character.js) in a page it did not write, and the page's newcomer fixes.

* an app page of this test's own (import map, its own renderer, scene, camera and render loop) puts two characters
  of the tiny site and a plain three.js mesh in one scene: the second moved and turned a quarter about z, both lit
  by one shared PRTLighting; each character's per-vertex radiance is the Python player's compiled CPU path for its
  pose seen from the app camera's eye in the character's own frame, the lighting turned into that frame (the
  second's by the angle minus the quarter turn), within the GPU decode tests' bound; the plain mesh shows in the
  frame and no console error is logged;
* the site's follow-camera track (``camera.follow[clip]``, (cx, cy, cz, radius) per frame) moves the page's camera
  to the Python player's ``camera_eye`` of that frame's centre and radius;
* the page opened from disk (file://) says on the page to serve it with ``prt web RUN --serve``;
* the page opens on the manifest's start clip and BRDF (the Python player's default BRDF; the run's held-out clip);
* the floor receives the sun's learned shadow: its vertices' visible fractions are onnxruntime's of the site's peak
  graph on the same receivers, some in shadow, and its irradiance is a quadrature of the residual lighting over the
  upper hemisphere.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from tests.tolerance import two_path_atol
from tests.web.test_errors import site_copy
from tests.web.test_gpu_decode import (
    SH_ROUNDINGS,
    decode_bound,
    grazing,
    rounded_latent,
    shade_with_latent,
    shading_columns,
)

APP = """<!doctype html>
<html><head><meta charset="utf-8"><link rel="icon" href="data:,">
<script type="importmap">
{ "imports": { "three": "./vendor/three/three.module.js", "onnxruntime-web": "./vendor/ort/ort.wasm.min.mjs",
               "prt-torch-web": "./prt-character.js" } }
</script></head>
<body><canvas id="c" width="640" height="480"></canvas>
<script type="module">
import * as THREE from 'three';
import { PRTCharacter, PRTLighting } from 'prt-torch-web';
try {
  const P = %(params)s;
  const renderer = new THREE.WebGLRenderer({ canvas: document.getElementById('c'), preserveDrawingBuffer: true });
  renderer.setSize(640, 480, false);
  const scene = new THREE.Scene();
  scene.background = new THREE.Color(0.1, 0.1, 0.1);
  const camera = new THREE.PerspectiveCamera(30, 640 / 480, 0.01 * P.radius, 100 * P.radius);
  camera.up.set(0, 0, 1);
  camera.position.set(...P.eye);
  camera.lookAt(...P.target);
  const lighting = new PRTLighting({ preset: 'sky', angle: P.angle, peaks: false });
  const a = await PRTCharacter.load('assets/', { renderer, lighting, brdf: P.brdf });
  const b = await PRTCharacter.load('assets/manifest.json', { renderer, lighting, brdf: P.brdf });
  b.position.set(...P.offset);
  b.rotation.z = Math.PI / 2;
  const box = new THREE.Mesh(new THREE.BoxGeometry(P.box, P.box, P.box),
    new THREE.MeshBasicMaterial({ color: 0xff0000 }));
  box.position.set(...P.boxAt);
  scene.add(a, b, box);
  a.setPose(P.poses[0][0], P.poses[0][1]);
  b.setPose(P.poses[1][0], P.poses[1][1]);
  await Promise.all([a.update(), b.update()]);
  renderer.render(scene, camera);
  const of = (c) => ({ radiance: Array.from(c.radiance(renderer)), eye: c.eyeLocal.toArray(),
    latent: { data: Array.from(c.lastLatent.data), dims: Array.from(c.lastLatent.dims) } });
  const gl = renderer.getContext();
  const px = new Uint8Array(640 * 480 * 4);
  gl.readPixels(0, 0, 640, 480, gl.RGBA, gl.UNSIGNED_BYTE, px);
  window.result = { a: of(a), b: of(b),
    redPixels: Array.from({ length: 640 * 480 }, (_, i) => i)
      .filter((i) => px[4 * i] > 200 && px[4 * i + 1] < 60).length,
    objects: scene.children.length };
} catch (e) {
  window.result = { error: e.message || String(e) };
}
</script></body></html>
"""


def test_two_characters_and_a_mesh_in_an_app_scene(checked_site: tuple[Path, Any], browser: Any, compiled: Any,
                                                   player: Any, decode: dict[str, Any], tmp_path: Path) -> None:
    from prt_torch.web.serve import SiteServer
    from prt_torch.web.site import read_manifest, site_local

    site = site_copy(checked_site[0], tmp_path / "site")
    m = read_manifest(site)
    center, radius = np.asarray(m["camera"]["center"]), float(m["camera"]["radius"])
    offset = np.array([0.8 * radius, 0.0, 0.0])
    angle, brdf = 0.3, "phong"
    poses = [("wave", 4), ("squat", 6)]
    params = {"radius": radius, "eye": (center + offset / 2 + [0.3 * radius, -3.0 * radius, 0.6 * radius]).tolist(),
              "target": (center + offset / 2).tolist(), "angle": angle, "brdf": brdf, "offset": offset.tolist(),
              "box": 0.2 * radius, "boxAt": (center - offset * 0.6).tolist(), "poses": poses}
    (site / "app.html").write_text(APP % {"params": json.dumps(params)})
    with SiteServer(site) as srv:
        ps = browser.open(srv.url + "app.html")
        try:
            ps.page.wait_for_function("window.result !== undefined", timeout=60000)
            res = ps.page.evaluate("window.result")
            assert ps.errors == []
        finally:
            ps.page.close()
    assert "error" not in res, res.get("error")
    assert res["objects"] == 3 and res["redPixels"] > 50, "the plain three.js mesh does not show"
    c_count = player.order ** 2
    got = {}
    # character b stands turned a quarter about z: the world's light, turned by `angle`, is turned back by a quarter
    # in its frame; its eye is the camera's in that frame
    for key, (clip, frame), turn in (("a", poses[0], angle), ("b", poses[1], angle - np.pi / 2)):
        for p in (player, compiled):
            p.set_brdf(brdf)
            p.light_angle = 0.0
            p.rotate_light(turn)
        r = res[key]
        state = compiled.poser(site_local(compiled.character, clip, frame), np.asarray(r["eye"], np.float64))
        z = np.reshape(r["latent"]["data"], r["latent"]["dims"])[:1].astype(np.float32)
        want = shade_with_latent(compiled, state, z)
        zhat = rounded_latent(compiled, z, decode["entry"]["groups"])
        bound = np.einsum("cvk,vc->vk", np.abs(shading_columns(player, state, c_count)),
                          decode_bound(decode, zhat, c_count))
        atol = two_path_atol(SH_ROUNDINGS, float(np.abs(want).max())) + bound
        rad = np.reshape(r["radiance"], (-1, 3))
        err = np.abs(rad - want)
        keep = ~grazing(state)
        assert (err <= atol)[keep].all(), (key, float((err - atol)[keep].max()))
        got[key] = rad
    # b's eye in its own frame is not a's: the object's transform reaches the shading
    assert np.linalg.norm(np.subtract(res["a"]["eye"], res["b"]["eye"])) > 0.1 * radius
    assert np.abs(got["a"] - got["b"]).max() > 20 * two_path_atol(SH_ROUNDINGS, float(np.abs(got["a"]).max()))


def test_follow_camera_track_moves_the_page_camera(checked_site: tuple[Path, Any], browser: Any,
                                                   tmp_path: Path) -> None:
    from prt_torch.player.player import camera_eye
    from prt_torch.web.serve import SiteServer
    from prt_torch.web.site import ASSETS, MANIFEST

    site = site_copy(checked_site[0], tmp_path / "site")
    p = site / ASSETS / MANIFEST
    m = json.loads(p.read_text())
    clip = next(c for c in m["clips"] if c["name"] == "wave")
    center, radius = np.asarray(m["camera"]["center"]), float(m["camera"]["radius"])
    t = np.arange(clip["frames"])
    track = np.stack([center[0] + 0.05 * radius * t, center[1] - 0.02 * radius * t, center[2] + 0 * t,
                      radius * (1 + 0.1 * t)], 1)
    m["camera"]["follow"] = {"wave": track.reshape(-1).tolist()}
    p.write_text(json.dumps(m))
    with SiteServer(site) as srv:
        ps = browser.open(srv.url + "?paused")
        try:
            assert ps.wait_ready(), ps.page.evaluate("window.prt.error")
            eyes = {}
            for name, frame in (("wave", 5), ("wave", 9), ("walk", 5)):
                ps.frame({"clip": name, "frame": frame, "playing": False, "peaks": False, "camera": "follow"})
                eyes[(name, frame)] = np.asarray(ps.page.evaluate("window.prt.crowd().eye"))
            assert ps.errors == []
        finally:
            ps.page.close()
    az, el = m["camera"]["azimuth"], m["camera"]["elevation"]
    for f in (5, 9):
        want = camera_eye(track[f, :3], float(track[f, 3]), az, el)
        np.testing.assert_allclose(eyes[("wave", f)], want, rtol=0, atol=1e-6 * radius)
    # a clip without a track keeps the fixed centre and radius
    np.testing.assert_allclose(eyes[("walk", 5)], camera_eye(center, radius, az, el), rtol=0, atol=1e-6 * radius)


def test_page_from_disk_says_to_serve_it(checked_site: tuple[Path, Any], browser: Any) -> None:
    ps = browser.open((checked_site[0] / "index.html").resolve().as_uri())
    try:
        assert ps.wait_ready(timeout_ms=30000) is False
        text = ps.page.locator("#error").inner_text()
        assert ps.page.locator("#error").is_visible() and ps.page.locator("[role=alert]:visible").count() == 1
        assert text.startswith("The player could not start:") and "file://" in text and "--serve" in text, text
        assert "prt web" in text and ps.page.locator("#stats").inner_text() == "error"
    finally:
        ps.page.close()


def test_page_opens_on_the_start_clip_and_brdf(checked_site: tuple[Path, Any], browser: Any, site_url: str,
                                               tiny_run: Path) -> None:
    from prt_torch.player.bundle import RunBundle
    from prt_torch.player.material import default_brdf
    from prt_torch.web.site import read_manifest

    m = read_manifest(checked_site[0])
    run = RunBundle(tiny_run, threads=1, graphs=("visibility",))
    cfg = run.run.dataset().run_config()
    held = [e if isinstance(e, str) else e.clip for e in cfg.character.heldout_clips]
    assert held, "the tiny run holds a clip out"
    st = m["start"]
    assert st["clip"] == held[0] and "held out" in st["clip_why"]  # the first held-out clip, said as much
    assert st["brdf"] == default_brdf(run)
    ps = browser.open(site_url)  # playing, as a newcomer opens it
    try:
        assert ps.wait_ready(), ps.page.evaluate("window.prt.error")
        got = ps.page.evaluate("() => ({clip: window.prt.app.clipInfo.name, brdf: window.prt.app.m.rpos["
                               "window.prt.app.brdf].name, note: document.getElementById('clipNote').textContent, "
                               "floor: window.prt.app.floor.position.z, inScene: window.prt.app.floor.parent === "
                               "window.prt.app.character})")
        assert ps.errors == []
    finally:
        ps.page.close()
    assert got["clip"] == st["clip"] and got["brdf"] == st["brdf"] and st["clip"] in got["note"]
    lowest = float(run.character.rest_vertices[:, 2].min())  # the floor just under the rest feet
    assert got["inScene"] and lowest - 0.01 * m["camera"]["radius"] < got["floor"] < lowest


def test_site_copies_the_module(checked_site: tuple[Path, Any]) -> None:
    from prt_torch.web.site import web_root

    for name in ("prt-character.js", "posing.js", "shading.js", "prt_shading.glsl"):
        assert (checked_site[0] / name).read_bytes() == (web_root() / "src" / name).read_bytes()
    pkg = json.loads((web_root() / "package.json").read_text())
    assert pkg["exports"]["."] == "./src/prt-character.js" and "three" in pkg["peerDependencies"]
    assert "three" not in pkg.get("dependencies", {})


def test_shipped_example_plays_two_characters(checked_site: tuple[Path, Any], browser: Any, site_url: str) -> None:
    """The site's example.html (two characters, a three.js mesh lit by three.js lights, a floor) plays frames."""
    ps = browser.open(site_url + "example.html")
    try:
        ps.page.wait_for_function("window.example && window.example.ready", timeout=60000)
        assert ps.page.evaluate("window.example.ready.then(a => a !== null)"), ps.page.evaluate("window.example.error")
        ps.page.wait_for_function("window.example.ready.then(a => a.frames() >= 3)", timeout=60000)
        got = ps.page.evaluate("window.example.ready.then(a => ({n: a.scene.children.length, "
                               "chars: a.characters.map((c) => c.clipInfo.name), error: window.example.error}))")
        assert ps.errors == [] and got["error"] is None
    finally:
        ps.page.close()
    assert got["n"] == 6 and len(got["chars"]) == 2


def test_floor_receives_the_suns_learned_shadow(checked_site: tuple[Path, Any], page: Any) -> None:
    from prt_torch.sh.basis import sh_basis
    from prt_torch.web.peaks import PeakGraph
    from prt_torch.web.site import ASSETS, PEAKS_MODEL, read_manifest

    m = read_manifest(checked_site[0])
    sky = next(x for x in m["lights"] if x["name"] == "sky")
    assert sky["peaks"], "the tiny site's sky has its sun apart"
    brdf = next(r["name"] for r in m["rpos"] if r["brdf"])  # an analytic BRDF: the peaks are shaded
    page.frame({"light": "sky", "camera": "fixed", "playing": False, "unshadowed": False, "perPixel": False,
                "peaks": True, "clip": "wave", "frame": 4, "brdf": brdf, "lightAngle": 0.3, "tonemap": None,
                "floor": True})
    fl = page.page.evaluate("window.prt.floor()")
    pk = page.page.evaluate("window.prt.activePeaks()")
    n, n_p = len(fl["points"]) // 3, len(pk["angular_radii"])
    pts = np.reshape(fl["points"], (1, n, 3)).astype(np.float32)
    nrm = np.broadcast_to(np.array([0, 0, 1], np.float32), (1, n, 3))
    skin = np.reshape(fl["skin"], (1, -1, 4, 4)).astype(np.float32)
    want = PeakGraph(checked_site[0] / ASSETS / PEAKS_MODEL)(
        pts, nrm, skin, np.reshape(pk["directions"], (-1, 3)).astype(np.float32),
        np.asarray(pk["angular_radii"], np.float32))[0]  # (n, P)
    got = np.reshape(fl["visibility"], (n, 4))[:, :n_p]
    assert np.linalg.norm(got - want) <= 1e-5 * np.linalg.norm(want)
    assert (want < 0.5).any(), "the character casts no sun shadow on the floor"
    assert (want > 0.999).mean() > 0.5, "the shadow covers most of the floor"
    # the residual lighting's irradiance at +z: a quadrature of sum_lm f_lm y_lm(w) cos(theta) over the upper
    # hemisphere (midpoint rule in (cos theta, phi)), f_lm = sum_k g_kl y_lm(s_k)
    order = m["order"]
    res = sky["peaks"]
    f = sum(sh_basis(np.asarray(d, np.float64) / np.linalg.norm(d), order)[:, None] *
            np.repeat(np.asarray(g, np.float64), [2 * band + 1 for band in range(order)], axis=0)
            for d, g in zip(res["dirs"], res["coeffs"], strict=True))  # (C, 3)
    nu, nphi = 400, 800
    mu = (np.arange(nu) + 0.5) / nu
    phi = (np.arange(nphi) + 0.5) / nphi * 2 * np.pi
    mm, pp = np.meshgrid(mu, phi, indexing="ij")
    s = np.sqrt(1 - mm ** 2)
    w = np.stack([s * np.cos(pp), s * np.sin(pp), mm], -1).reshape(-1, 3)
    e_ref = (sh_basis(w, order) @ f * mm.reshape(-1, 1)).sum(0) * (1 / nu) * (2 * np.pi / nphi)
    np.testing.assert_allclose(fl["irradiance"], e_ref, rtol=1e-4, atol=1e-4 * np.abs(e_ref).max())
    # the colours: albedo / pi (E + sum_p E_p max(l_p.z, 0) V_p), tone-mapped with the lighting's peaks-on tone map
    tm = res["tonemap"]
    lz = np.maximum(np.reshape(pk["directions"], (-1, 3))[:, 2], 0)
    irr = np.asarray(fl["irradiance"])[None] + (got * lz[None]) @ np.asarray(res["powers"])  # (n, 3)
    x = np.maximum(np.asarray(fl["albedo"])[None] / np.pi * irr * tm["exposure"], 0)
    col = np.minimum(x * (1 + x / tm["white"] ** 2) / (1 + x), 1) ** (1 / m["tonemap"]["gamma"])
    np.testing.assert_allclose(np.reshape(fl["colors"], (n, 3)), col, rtol=1e-5, atol=1e-6)
    lit = col[want[:, 0] > 0.999].mean()
    assert col[want[:, 0] < 0.5].mean() < lit, "the shadow does not darken the floor"

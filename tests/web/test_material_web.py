"""A textured character in both players: the base colour multiplies the radiance (per vertex in the Python
player, per pixel - or per vertex, matching the Python player - on the page)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from prt_torch.scoring.statistics import image_psnr
from tests.textured import textured_copy


def _textured_run(tiny_run: Path, dst: Path) -> Path:
    """A copy of the tiny run whose character has a colourful checker texture through per-corner UVs
    (:func:`tests.textured.textured_copy`)."""
    return textured_copy(tiny_run, dst, ignore=("dataset.zarr", "compare", "report", "*.mp4"))


def test_textured_character_page_matches_player_and_samples_per_pixel(tiny_run: Path, chromium: str, browser: Any,
                                                                       tmp_path: Path) -> None:
    from prt_torch.player.material import vertex_base_color
    from prt_torch.rundir import RunDir
    from prt_torch.web.check import check_site, served_page
    from prt_torch.web.site import read_manifest, write_site

    run = _textured_run(tiny_run, tmp_path / "run")
    ch = RunDir(run).character()
    base = vertex_base_color(ch)
    assert base is not None and base.std(0).min() > 0.05  # the texture varies over the body
    site = tmp_path / "site"
    write_site(run, site, material_rpo=False, env_presets=False)
    m = read_manifest(site)
    assert m["material"]["texture"] and m["material"]["roughness"] == 0.4
    case = [{"clip": "wave", "frame": 5, "brdf": m["default_brdf"], "lightAngle": 0.3}]
    res = check_site(site, run, chromium=chromium, artifacts=tmp_path / "check", cases=case, timing_steps=1,
                     play_seconds=0, browser=browser)
    assert res["console_errors"] == [] and res["psnr_vs_player"] >= 35.0, res
    with served_page(site, chromium, browser=browser) as ps:
        assert ps.wait_ready()
        state = {"clip": "wave", "frame": 5, "light": "sky", "lightAngle": 0.3, "playing": False}
        per_vertex, _ = ps.frame({**state, "perPixel": False})
        per_pixel, _ = ps.frame({**state, "perPixel": True})
        assert ps.errors == []
    body = per_vertex.sum(-1) > 3 * 40
    # per-pixel texturing shows the checker's edges inside triangles: a different, but related, frame
    assert 15.0 < image_psnr(per_pixel, per_vertex, body) < 45.0


def test_page_opens_on_the_characters_own_material(tiny_run: Path, browser: Any, tmp_path: Path) -> None:
    """A character with its own material: the site's start BRDF is ``material`` (the Python player's default) and the
    page opens on it; its tone map is the Python player's for that BRDF on the start clip's first frame."""
    from prt_torch.player.lighting import load_lighting
    from prt_torch.player.player import Player
    from prt_torch.web.check import served_page
    from prt_torch.web.site import read_manifest, site_local, write_site

    run = _textured_run(tiny_run, tmp_path / "run")
    site = tmp_path / "site"
    write_site(run, site, material_rpo=True, env_presets=False)
    m = read_manifest(site)
    assert m["start"]["brdf"] == "material" and "material" in [r["name"] for r in m["rpos"]]
    p = Player(run, threads=1, graph="split")  # its default BRDF: the character's own material
    try:
        p.lighting = load_lighting(None, p.order)
        p.rotate_light(0.0)
        state = p.pose(site_local(p.character, m["start"]["clip"], 0))
        p.exposure = None
        p.colors(p.shade(state)[0])  # fixes the tone map from this first frame
        want = p.exposure
    finally:
        p.close()
    with served_page(site, browser=browser, query="") as ps:
        assert ps.wait_ready(), ps.page.evaluate("window.prt.error")
        got = ps.page.evaluate("window.prt.app.m.rpos[window.prt.app.brdf].name")
        assert ps.errors == []
    assert got == "material"
    sky = m["lights"][0]["tonemap"]
    assert abs(sky["exposure"] - want.exposure) <= 1e-6 * want.exposure

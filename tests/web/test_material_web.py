"""A textured character in both players: the base colour multiplies the radiance (per vertex in the Python
player, per pixel - or per vertex, matching the Python player - on the page)."""

from __future__ import annotations

import shutil
from pathlib import Path
from typing import Any

import numpy as np

from prt_torch.scoring.statistics import image_psnr


def _textured_run(tiny_run: Path, dst: Path) -> Path:
    """A copy of the tiny run whose character has a colourful checker texture through per-corner UVs (a material
    is not part of the character hash, so the export still matches)."""
    from prt_torch.rig.material import Material
    from prt_torch.rundir import RunDir

    shutil.copytree(tiny_run, dst, ignore=shutil.ignore_patterns("dataset.zarr", "compare", "report", "*.mp4"))
    run = RunDir(dst)
    ch = run.character()
    yy, xx = np.mgrid[0:64, 0:64]
    tex = np.stack([(xx * 4) % 256, (yy * 4) % 256, 255 * (((xx // 8) + (yy // 8)) % 2)], -1).astype(np.uint8)
    lo, hi = ch.rest_vertices.min(0), ch.rest_vertices.max(0)
    x, z = ch.rest_vertices[:, 0], ch.rest_vertices[:, 2]
    uv_v = np.stack([(x - lo[0]) / (hi[0] - lo[0]), (hi[2] - z) / (hi[2] - lo[2])], 1)
    ch.uv = uv_v[ch.faces].astype(np.float32)
    ch.material = Material("checker", (1.0, 0.9, 0.8, 1.0), 0.0, 0.4, tex)
    ch.save(run.character_path)
    return dst


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

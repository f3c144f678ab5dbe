"""``prt compare`` scores the look ``prt play`` shows (issue 27, item 0): a textured glTF character's base-colour
texture and its material's Cook-Torrance RPO in every row of the strip, the Monte-Carlo reference included, and in
every PSNR, by the player's own rule (:class:`prt_torch.player.material.SurfaceAlbedo`).

The textured character: a copy of ``gltf_run`` (the synthetic glTF figure, its own material, exported) whose
character gets per-corner planar UVs and a checker texture (the material and the UVs are not part of the character
hash: the dataset and the export still verify)."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from prt_torch.rig.material import MATERIAL_BRDF
from tests.textured import CHECKER_ROUGHNESS, textured_copy
from tests.tolerance import assert_bitwise


@pytest.fixture(scope="module")
def textured_run(gltf_run: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A copy of ``gltf_run`` (dataset and export included) whose character is textured."""
    return textured_copy(gltf_run, tmp_path_factory.mktemp("textured_compare") / "run")


def test_compare_shades_and_renders_what_the_player_plays(textured_run: Path) -> None:
    """(a) One pose, light and camera: compare's shading radiance (its RPOs through the scoring shader) equals the
    Python player's per vertex, and compare's image of it equals the player's rendered frame.

    Tolerances from the arithmetic: both shade the same float32 RPO, lobes and visibility (onnxruntime vs torch:
    reassociated float32 sums), so the radiance agrees to ~1e-6 relative (asserted < 1e-4, as the deformable
    player's test); a relative change e of the radiance moves an 8-bit colour by at most ~255 e < 0.03 of a level,
    so the images may differ only where a colour sits on a rounding boundary: by at most 1 level, at few pixels."""
    from prt_torch.compare.run import load_compare_run, strip_brdf
    from prt_torch.player import Player
    from prt_torch.player.material import surface_albedo
    from prt_torch.scoring.images import ImageRenderer, player_camera
    from prt_torch.scoring.rpos import player_brdfs
    from prt_torch.scoring.shading import ShippingShader

    p = Player(textured_run, graph="split")
    try:
        assert p.rpo.name == MATERIAL_BRDF  # a character with its own material plays it by default
        ctx = load_compare_run(textured_run)
        rpos, brdfs = player_brdfs(ctx.order, ctx.run, ctx.character)
        assert list(rpos) == ["lambert", "phong", MATERIAL_BRDF] and strip_brdf(rpos) == MATERIAL_BRDF
        k = rpos[MATERIAL_BRDF].M.shape[0]
        assert_bitwise(np.asarray(rpos[MATERIAL_BRDF].M, np.float32), p.rpo.M[:k], why="one RPO file, loaded twice")
        assert brdfs[MATERIAL_BRDF].roughness == pytest.approx(CHECKER_ROUGHNESS)
        camera = player_camera(ctx.character)
        np.testing.assert_allclose(camera.eye, p.eye, rtol=0, atol=1e-6)
        state = p.pose(p.clip_locals("twist")[3:4])
        vis = p.visibility(state.features)
        played = p.shade(state, visibility=vis)[0]  # (V, 3), the player's radiance
        pos = state.positions_vx3(0)
        shader = ShippingShader({"light": p.lighting}, rpos, camera.eye, paths=("lobes",))
        ours = shader.shade_chunk({"m": vis}, state.frames_vx33(), pos[None])[("light", MATERIAL_BRDF, "lobes")]["m"][0]
        assert float(np.abs(ours - played).max() / np.abs(played).max()) < 1e-4

        img_player = p.render_frame(state, played[None])  # fixes the player's tone map from this frame
        albedo = surface_albedo(ctx.character)
        assert albedo.texture is not None and albedo.vertex is not None
        with ImageRenderer(ctx.character.rest_vertices, ctx.character.faces, camera, albedo=albedo) as r:
            fi = r.frame_images(pos, {"truth": ours}, "truth")
            img_ours = fi.images["truth"]
            assert fi.tonemap.exposure == pytest.approx(p.exposure.exposure, rel=1e-4)
            with ImageRenderer(ctx.character.rest_vertices, ctx.character.faces, camera) as plain:
                img_plain = plain.frame_images(pos, {"truth": ours}, "truth").images["truth"]
        d = np.abs(img_ours.astype(int) - img_player.astype(int))
        m = fi.mask
        assert m.sum() > 500
        assert d.max() <= 1 and (d[m] > 0).mean() < 0.02
        # the texture matters: the untextured image (what compare rendered before) is far from the played one
        assert np.abs(img_plain.astype(int) - img_player.astype(int))[m].mean() > 5.0
    finally:
        p.close()


def _directional_albedo(brdf: Any, wo: np.ndarray, n_theta: int = 256, n_phi: int = 512) -> np.ndarray:
    """``(V, 3)``: ``int_H f(wi, wo) cos(theta_i) dwi`` for local ``wo (V, 3)`` by a midpoint rule in
    ``(cos theta, phi)`` (an independent quadrature, not the reference's sampler)."""
    mu = (np.arange(n_theta) + 0.5) / n_theta
    phi = (np.arange(n_phi) + 0.5) / n_phi * 2 * math.pi
    mu, phi = np.meshgrid(mu, phi, indexing="ij")
    s = np.sqrt(1 - mu ** 2)
    wi = np.stack([s * np.cos(phi), s * np.sin(phi), mu], -1).reshape(-1, 3)
    w = (2 * math.pi / (n_theta * n_phi)) * wi[:, 2]  # dwi = d(cos) dphi, times cos(theta_i)
    out = np.empty((len(wo), 3))
    for i, o in enumerate(wo):
        out[i] = (brdf(wi, np.broadcast_to(o, wi.shape)) * w[:, None]).sum(0)
    return out


def test_reference_uses_the_same_albedo_and_material(textured_run: Path) -> None:
    """(b) The reference's surface radiance of an unoccluded vertex under a uniform sky of radiance 1 is
    ``albedo(vertex) x int f cos`` of compare's BRDF (lambert: its tint; the material: the Cook-Torrance it was built
    from, against an independent quadrature), within the Monte-Carlo error of the pair (both estimates' spread)."""
    from prt_torch.compare.reference import ReferenceLight, reference_pair
    from prt_torch.compare.run import heldout_frames, load_compare_run
    from prt_torch.player.material import surface_albedo
    from prt_torch.scoring.images import player_camera
    from prt_torch.scoring.rpos import player_brdfs

    ctx = load_compare_run(textured_run)
    fs = heldout_frames(ctx, max_frames=1)
    rpos, brdfs = player_brdfs(ctx.order, ctx.run, ctx.character)
    eye = player_camera(ctx.character).eye
    pos, frames = fs.positions[0].astype(np.float64), fs.frames[0].astype(np.float64)
    light = ReferenceLight(lambda d: np.ones((len(d), 3)), [], "uniform 1")
    # the scene is one tiny triangle a million units away: nothing occludes any vertex (solid angle ~1e-12)
    pts = np.concatenate([pos, 1e6 + np.eye(3)])
    far = np.array([[0, 1, 2]]) + len(pos)
    pair = reference_pair(pts, np.concatenate([frames, np.broadcast_to(np.eye(3), (3, 3, 3))]), far, eye, light,
                          brdfs, 512, 1e-4)
    albedo = surface_albedo(ctx.character)
    view = eye - pos
    view /= np.linalg.norm(view, axis=1, keepdims=True)
    wo = np.einsum("vij,vj->vi", frames, view)
    front = wo[:, 2] > 0.2
    assert front.sum() > 20
    assert MATERIAL_BRDF in rpos
    for b in ("lambert", MATERIAL_BRDF):
        got = albedo.apply(pair.mean[b][: len(pos)])[front]
        wo_f = wo[front] / np.linalg.norm(wo[front], axis=1)[:, None]
        want = albedo.vertex[front] * _directional_albedo(brdfs[b], wo_f)  # the player's per-vertex base colour
        spread = albedo.apply(pair.a[b][: len(pos)] - pair.b[b][: len(pos)])[front]
        err = float(np.sqrt(np.mean((got - want) ** 2)))
        noise = float(np.sqrt(np.mean(spread ** 2))) / 2  # the mean's error ~ |a - b| / 2
        assert err <= 3 * noise + 2e-3 * float(np.abs(want).mean()), (b, err, noise)
    # lambert's closed form: int (tint / pi) cos = tint, so the surface radiance is the albedo times the tint
    tint = np.asarray(brdfs["lambert"].tint, np.float64)
    np.testing.assert_allclose(albedo.apply(pair.mean["lambert"][: len(pos)])[front],
                               (albedo.vertex.astype(np.float64) * tint)[front], rtol=2e-2)


def test_compare_of_a_textured_character_scores_the_material(textured_run: Path,
                                                             monkeypatch: pytest.MonkeyPatch) -> None:
    """The whole command on the textured run: the material BRDF is scored beside the catalogue (same keys, tag
    ``material``), the JSON says the look used, and the reference row goes through the methods' albedo and tone
    rule: a reference equal to sh_truth's radiance scores sh_truth at (numerically) infinite PSNR for every BRDF.
    A reference rendered without the base colour would not."""
    import prt_torch.compare.run as run_mod
    from prt_torch.compare.reference import ReferencePair, silhouette_mask
    from prt_torch.player.lighting import load_lighting
    from prt_torch.scoring.rpos import player_brdfs
    from prt_torch.scoring.shading import ShippingShader

    ctx = run_mod.load_compare_run(textured_run)
    fs = run_mod.heldout_frames(ctx, max_frames=3)
    rpos, _ = player_brdfs(ctx.order, ctx.run, ctx.character)
    lighting = load_lighting(None, ctx.order)
    by_pos = {fs.positions[i].tobytes(): fs.baked_visibility[i] for i in range(fs.n_frames)}

    def truth_pair(positions: np.ndarray, frames: np.ndarray, faces: np.ndarray, eye: np.ndarray, *a: Any,
                   **k: Any) -> ReferencePair:
        vis = by_pos[np.asarray(positions, np.float32).tobytes()]
        sh = ShippingShader({"light": lighting}, rpos, eye, paths=("lobes",))
        res = sh.shade_chunk({"t": vis[None]}, frames[None], positions[None])
        front = silhouette_mask(positions, frames, eye)[:, None]  # the one silhouette rule of every row
        est = {b: res[("light", b, "lobes")]["t"][0].astype(np.float64) * front for b in rpos}
        return ReferencePair(est, est)

    monkeypatch.setattr(run_mod, "reference_pair", truth_pair)
    r = run_mod.run_compare(textured_run, methods=["unshadowed"], max_frames=3, image_frames=2,
                            reference_frames=1, reference_rays=8)
    assert r["brdfs"] == ["lambert", "phong", MATERIAL_BRDF] and r["strip_frame"]["brdf"] == MATERIAL_BRDF
    assert r["material"]["has_texture"] and r["material"]["roughness"] == pytest.approx(CHECKER_ROUGHNESS)
    assert "texture" in r["material"]["albedo"]
    for m in r["methods"].values():
        for key in ("psnr_image_material", "radiance_rel_rmse_material", "psnr_vertex_material"):
            assert key in m and key in m["vs_reference"], key
    t = r["methods"]["sh_truth"]["vs_reference"]
    for tag in ("diffuse", "glossy", MATERIAL_BRDF):
        # sh_truth is traced here, the stub shades the baked visibility (equal to 1e-6): a colour level flipped at a
        # few pixels at most; a reference without the base colour would sit some 10 dB below the unshadowed row
        assert t[f"psnr_image_{tag}"] > 60.0, tag
        assert t[f"radiance_rel_rmse_{tag}"] < 1e-4, tag
    u = r["methods"]["unshadowed"]
    assert np.isfinite(u["psnr_image_material"]) and u["vs_reference"]["psnr_image_material"] < 60.0


def test_a_white_character_scores_as_before(small_run: Path) -> None:
    """(c) The built-in character (no material of its own, white): the catalogue BRDFs only, and images and vertex
    figures bit-for-bit those of the albedo-free path compare used before."""
    from prt_torch.compare.run import heldout_frames, load_compare_run, strip_brdf
    from prt_torch.player.lighting import load_lighting
    from prt_torch.player.material import surface_albedo
    from prt_torch.scoring.images import ImageRenderer, player_camera
    from prt_torch.scoring.rpos import player_brdfs, shipping_rpos
    from prt_torch.scoring.shading import ShippingShader

    ctx = load_compare_run(small_run)
    rpos, brdfs = player_brdfs(ctx.order, ctx.run, ctx.character)
    assert list(rpos) == list(shipping_rpos(ctx.order, ctx.run)) == ["lambert", "phong"]
    assert strip_brdf(rpos) == "lambert" and set(brdfs) == set(rpos)
    albedo = surface_albedo(ctx.character)
    assert albedo.white
    fs = heldout_frames(ctx, max_frames=1)
    cam = player_camera(ctx.character)
    shader = ShippingShader({"light": load_lighting(None, ctx.order)}, rpos, cam.eye, paths=("lobes",))
    rad = shader.shade_all({"t": fs.baked_visibility, "u": np.ones(ctx.order ** 2, np.float32)}, fs.frames,
                           fs.positions)[("light", "lambert", "lobes")]
    assert albedo.apply(rad["t"]) is rad["t"]
    pos = fs.positions[0]
    with ImageRenderer(ctx.character.rest_vertices, ctx.character.faces, cam, albedo=albedo) as a, \
            ImageRenderer(ctx.character.rest_vertices, ctx.character.faces, cam) as b:
        fa = a.frame_images(pos, {"t": rad["t"][0], "u": rad["u"][0]}, "t")
        fb = b.frame_images(pos, {"t": rad["t"][0], "u": rad["u"][0]}, "t")
    for n in ("t", "u"):
        assert_bitwise(fa.images[n], fb.images[n], why="uint8: the same renderer, colours and tone map")
    assert fa.sse == fb.sse

"""The page in headless Chromium: JS posing vs the numpy reference, onnxruntime-web vs onnxruntime, and how BRDF
swap, light rotation and the unshadowed toggle change the frame (each against the Python player)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest

from prt_torch.scoring.statistics import image_psnr

SKY = {"light": "sky", "camera": "fixed", "playing": False, "unshadowed": False, "perPixel": False,
       "peaks": False}  # the whole sky on the SH path (the peaks: tests/web/test_page_peaks.py), the fixed camera


def _mask(player: Any, positions: np.ndarray) -> np.ndarray:
    from prt_torch.scoring.images import ImageRenderer, player_camera

    ch = player.character
    with ImageRenderer(ch.rest_vertices, ch.faces, player_camera(ch, (480, 640))) as r:
        return r.mask(positions)


def _player_frame(player: Any, clip: str, frame: int, brdf: str, angle: float, unshadowed: bool = False):
    from prt_torch.web.site import site_local

    local = site_local(player.character, clip, frame)
    player.set_brdf(brdf)
    player.light_angle = 0.0
    player.rotate_light(angle)
    state = player.pose(local)
    vis = np.broadcast_to(player.unshadowed, (1, state.frames.shape[2], player.order ** 2)) if unshadowed else None
    rad = player.shade(state, visibility=vis)
    return state, player.render_frame(state, rad)


def test_js_posing_equals_numpy_reference(page: Any, tiny_run: Path) -> None:
    from prt_torch.rig.features import pose_features
    from prt_torch.rig.skeleton import forward_kinematics
    from prt_torch.rig.vertex_frames import vertex_frames
    from prt_torch.rundir import RunDir
    from prt_torch.web.site import site_local

    run = RunDir(tiny_run)
    ch = run.character()
    with np.load(run.frames_path) as z:
        labels, axes, bones = z["cluster"], z["cluster_axis"], z["cluster_bone"]
    for clip, frame in (("wave", 3), ("squat", 5)):
        js = page.page.evaluate("a => window.prt.pose(a[0], a[1])", [clip, frame])
        local = site_local(ch, clip, frame)
        skin = forward_kinematics(ch.parents, local) @ ch.inverse_bind[None]  # (1, J, 4, 4)
        w = ch.dense_weights.astype(np.float64)  # (V, J)
        blend = np.einsum("vj,fjab->fvab", w, skin)[0]
        rest = np.concatenate([ch.rest_vertices, np.ones((ch.num_vertices, 1))], 1).astype(np.float64)
        pos = np.einsum("vab,vb->va", blend[:, :3], rest)
        nrm = np.einsum("vab,vb->va", blend[:, :3, :3], ch.rest_normals.astype(np.float64))
        nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
        frames = vertex_frames(nrm[None], skin, labels, axes, bones)[0]
        feats = pose_features(local, ch.bind_local, ch.parents)[0]
        scale = float(np.abs(ch.rest_vertices).max())
        np.testing.assert_allclose(np.reshape(js["positions"], (-1, 3)), pos, atol=2e-6 * scale)
        np.testing.assert_allclose(np.reshape(js["normals"], (-1, 3)), nrm, atol=2e-5)
        np.testing.assert_allclose(np.reshape(js["frames"], (-1, 3, 3)), frames, atol=2e-4)
        np.testing.assert_allclose(js["features"], feats, atol=1e-6)


def test_onnxruntime_web_visibility_equals_onnxruntime(page: Any, tiny_run: Path, player: Any) -> None:
    from prt_torch.web.site import site_local

    ch = player.character
    local = np.concatenate([site_local(ch, c, f) for c, f in (("walk", 1), ("wave", 4), ("stretch", 7))])
    feats = player.poser.features(local)
    web = np.reshape(page.page.evaluate("a => window.prt.visibility(a[0], a[1])",
                                        [feats.reshape(-1).astype(float).tolist(), len(feats)]), (len(feats), -1))
    from prt_torch.web.check import fp32_compute_session

    ref_player = player.visibility(feats).reshape(len(feats), -1)
    fp32 = fp32_compute_session(player.bundle.run.graph_path("visibility"))  # int8 graphs: onnxruntime-web's arithmetic
    ref = ref_player if fp32 is None else fp32.run(None, {"pose": feats})[0].reshape(len(feats), -1)
    rel = np.linalg.norm(web - ref, axis=1) / np.linalg.norm(ref, axis=1)
    assert rel.max() <= 1e-4, rel
    rel_player = np.linalg.norm(web - ref_player, axis=1) / np.linalg.norm(ref_player, axis=1)
    assert rel_player.max() <= 2e-3, rel_player  # at most the int8 activation rounding of native onnxruntime


def test_brdf_swap_changes_the_frame_as_the_player_does(page: Any, player: Any) -> None:
    imgs, refs = {}, {}
    for brdf in ("lambert", "phong"):
        state, refs[brdf] = _player_frame(player, "wave", 6, brdf, 0.0)
        imgs[brdf], _ = page.frame({**SKY, "clip": "wave", "frame": 6, "brdf": brdf, "lightAngle": 0.0})
    mask = _mask(player, state.positions_vx3(0))
    for b in imgs:
        assert image_psnr(imgs[b], refs[b], mask) >= 35.0, b
    assert image_psnr(imgs["lambert"], imgs["phong"], mask) < 35.0, "swapping the BRDF did not change the frame"
    d_page = (imgs["phong"].astype(float) - imgs["lambert"])[mask].ravel()
    d_ref = (refs["phong"].astype(float) - refs["lambert"])[mask].ravel()
    assert np.corrcoef(d_page, d_ref)[0, 1] > 0.95  # the same highlights appear where the player shows them


@pytest.mark.parametrize("angle", [np.pi])
def test_light_rotation_changes_the_frame_as_the_player_does(page: Any, player: Any, angle: float) -> None:
    base = {**SKY, "clip": "walk", "frame": 4, "brdf": "phong"}
    img0, _ = page.frame({**base, "lightAngle": 0.0})
    img_full, _ = page.frame({**base, "lightAngle": 2 * np.pi})
    img_rot, _ = page.frame({**base, "lightAngle": angle})
    state, ref0 = _player_frame(player, "walk", 4, "phong", 0.0)
    _, ref_rot = _player_frame(player, "walk", 4, "phong", angle)
    mask = _mask(player, state.positions_vx3(0))
    assert image_psnr(img_full, img0, mask) >= 50.0, "a full turn of the light must give the same frame"
    assert image_psnr(img_rot, ref_rot, mask) >= 35.0
    assert image_psnr(img_rot, img0, mask) < 30.0, "turning the sun behind the character did not change the frame"
    # the sun moves from in front of the character to behind it: the lit front gets darker, as in the player
    assert img_rot[mask].mean() < img0[mask].mean() - 5
    assert np.sign(img_rot[mask].mean() - img0[mask].mean()) == np.sign(ref_rot[mask].mean() - ref0[mask].mean())


def test_unshadowed_toggle_equals_player_unshadowed(page: Any, player: Any) -> None:
    base = {**SKY, "clip": "squat", "frame": 8, "brdf": "lambert", "lightAngle": 0.0}
    img_sh, _ = page.frame(base)
    img_un, _ = page.frame({**base, "unshadowed": True})
    state, ref_un = _player_frame(player, "squat", 8, "lambert", 0.0, unshadowed=True)
    mask = _mask(player, state.positions_vx3(0))
    assert image_psnr(img_un, ref_un, mask) >= 35.0
    assert image_psnr(img_un, img_sh, mask) < 45.0, "the learned shadows made no difference"
    assert img_un[mask].mean() >= img_sh[mask].mean()  # removing occlusion never darkens on average


def test_matrix_form_shader_equals_fused(browser: Any, site_url: str, page: Any) -> None:
    """prt_shading.glsl's eq. 11 as written (prtRadianceMatrix) and the fused order give the same frame."""
    state = {**SKY, "clip": "walk", "frame": 2, "brdf": "phong", "lightAngle": 0.7}
    fused, _ = page.frame(state)
    ps = browser.open(site_url + "?paused&form=matrix")
    try:
        assert ps.wait_ready(), ps.page.evaluate("window.prt.error")
        matrix, _ = ps.frame(state)
        assert ps.errors == []
    finally:
        ps.page.close()
    assert (fused.astype(int).sum(-1) > 3 * 60).sum() > 500, "the frame shows no lit character"
    assert np.abs(fused.astype(int) - matrix).max() <= 2


def test_keyboard_shortcuts_follow_the_python_player(page: Any) -> None:
    page.frame({**SKY, "clip": "walk", "frame": 0, "brdf": 0, "lightAngle": 0.0})
    get = "() => ({brdf: window.prt.app.brdf, angle: window.prt.app.lightAngle, az: window.prt.app.azimuth, " \
          "playing: window.prt.app.playing})"
    before = page.page.evaluate(get)
    for key in ("b", "l", "ArrowRight", " "):
        page.page.keyboard.press("Space" if key == " " else key)
    after = page.page.evaluate(get)
    n_brdf = page.page.evaluate("window.prt.app.m.rpos.length")
    assert after["brdf"] == (before["brdf"] + 1) % n_brdf
    assert after["angle"] == pytest.approx(before["angle"] + np.radians(15))
    assert after["az"] == pytest.approx(before["az"] + np.radians(10))
    assert after["playing"] != before["playing"]
    page.page.keyboard.press("r")  # the camera back where it was: the module's other tests share this page
    assert page.page.evaluate(get)["az"] == pytest.approx(before["az"])
    page.page.evaluate("s => window.prt.setState(s)", {"playing": False, "paused": True})

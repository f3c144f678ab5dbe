"""The page's GPU decode (issue 28 item 5): onnxruntime-web runs the latent graph only (pose -> z), the vertex shader
decodes each vertex's visibility from the site's float16 bases and z and shades it.

* the page's per-vertex radiance equals the Python player's compiled CPU path (its own ``decode.npz`` int8 bases and
  int8-rounded z, :mod:`prt_torch.player.compiled`) on the same posed inputs and z, within float32 shading rounding
  plus a bound of what float16 bases and float32 decode sums can add, carried through the shading's linear map
  (its columns: the shading of each unit visibility vector, by the Python player's shading graph);
* onnxruntime-web's z equals onnxruntime's computing the float32 arithmetic onnxruntime-web implements
  (:func:`prt_torch.web.check.fp32_compute_session`; native onnxruntime's own int8 activation rounding moves z by
  a few 1e-3 relative on the tiny run, which is why the decode test above feeds the page native z);
* the texel layout puts the tiny character on many rows of a narrow texture (``?texwidth=``) with the same radiance,
  bit for bit, as one wide row - the layout only moves the fetches;
* K characters in one page each keep their own pose: character c's radiance is the compiled player's for its pose
  at its place in the grid, seen from the crowd's camera;
* ``prt bench web`` runs and prints its keys (no timing asserted).
"""

from __future__ import annotations

import contextlib
import io
import json
from pathlib import Path
from typing import Any

import numpy as np

from tests.tolerance import assert_bitwise, two_path_atol

SKY = {"light": "sky", "camera": "fixed", "playing": False, "unshadowed": False, "perPixel": False, "peaks": False}
#: roundings of the page's SH shading along its longest chain (tests/web/test_page_peaks.py's SH_ROUNDINGS)
SH_ROUNDINGS = 256
#: float16's unit roundoff (11 significant bits) and its smallest normal's spacing (subnormal absolute rounding)
F16_U, F16_ABS = 2.0 ** -11, 2.0 ** -25
F32_U = 2.0 ** -24


def _inputs(state: Any, z: np.ndarray) -> dict[str, Any]:
    """``window.prt.radiance`` inputs of a Python-posed batch of one and its z ``(1, Gz, Kz)``: no visibility (the
    page decodes it), peaks unshadowed."""
    n_v = state.positions.shape[2]
    return {"positions": state.positions[0].T.reshape(-1).astype(float).tolist(),
            "frames": state.frames_vx33()[0].reshape(-1).astype(float).tolist(),
            "peakVisibility": np.ones(4 * n_v).tolist(),
            "latent": z.reshape(-1).astype(float).tolist(), "latentDims": list(z.shape)}


def rounded_latent(compiled: Any, z: np.ndarray, groups: list[dict[str, int]]) -> np.ndarray:
    """``(G, K)`` float64: z rounded as the CPU path rounds it (:func:`~prt_torch.player.frame_kernels.
    quantize_latent`, the player's own call), per site cluster ``g`` (its ``row`` of z)."""
    from prt_torch.player.frame_kernels import quantize_latent

    cf = compiled.compiled
    blocks = cf.blocks if cf.int8 else np.zeros_like(cf.blocks)
    zq, zs = quantize_latent(np.ascontiguousarray(z, np.float32), cf.rows, cf.k_used, blocks, cf.k_pad, cf.nb_max)
    out = np.zeros((len(groups), cf.k_pad))
    for g, grp in enumerate(groups):  # clusters (tens)
        i = int(np.flatnonzero(cf.rows == grp["row"])[0])
        k = np.arange(grp["k_used"])
        blk = max(grp["block"], 1)
        out[g, :len(k)] = zq[0, i, k] * (zs[0, i, k // blk] if grp["block"] else 1.0)
    return out


def decode_bound(dec: dict[str, Any], zhat: np.ndarray, n_coeffs: int) -> np.ndarray:
    """``(V, C)`` bound of what the page's decode adds to the exact ``mean + sum_k zhat_k b_k``: each float16 entry
    rounded by at most ``2^-11`` of itself (+ ``2^-25`` absolute below float16's normal range), a float32 sum of
    ``K + 1`` products on each side (the page's and the CPU path's): ``2 gamma_{K+2}`` of the terms' magnitudes."""
    basis = np.abs(dec["basis"][:, :, :n_coeffs].astype(np.float64))  # (V, K + 1, C)
    zv = np.abs(zhat[dec["rows"][:, 0]])[:, :basis.shape[1] - 1]  # (V, K)
    terms = basis[:, 0] + np.einsum("vk,vkc->vc", zv, basis[:, 1:])
    n = basis.shape[1] + 1
    return F16_U * terms + F16_ABS * (1.0 + zv.sum(1))[:, None] + 2 * n * F32_U / (1 - n * F32_U) * terms


def shading_columns(player: Any, state: Any, n_coeffs: int) -> np.ndarray:
    """``(C, V, 3)``: the Python player's shading of each unit visibility vector ``e_c`` (the columns of the linear
    map visibility -> radiance at these vertices, the player's current BRDF and lighting)."""
    n_v = state.positions.shape[2]
    cols = []
    for c in range(n_coeffs):
        e = np.zeros((1, n_v, n_coeffs), np.float32)
        e[..., c] = 1.0
        cols.append(player.shade(state, visibility=e)[0])
    return np.stack(cols).astype(np.float64)


class _GivenLatent:
    """A stand-in for the compiled player's latent graph that returns a given ``z`` (the page's)."""

    def __init__(self, z: np.ndarray) -> None:
        self.z = z

    def run_unchecked(self, feeds: dict[str, np.ndarray]) -> list[np.ndarray]:
        return [self.z]


def shade_with_latent(compiled: Any, state: Any, z: np.ndarray) -> np.ndarray:
    """``(V, 3)`` float64: the compiled player's radiance of ``state`` decoded from ``z (1, Gz, Kz)``."""
    graph = compiled.compiled.latent
    compiled.compiled.latent = _GivenLatent(z)
    try:
        return compiled.shade(state)[0].astype(np.float64)
    finally:
        compiled.compiled.latent = graph


def grazing(state: Any, eps: float = 1e-4) -> np.ndarray:
    n = state.normals[0].T.astype(np.float64)
    v = state.view_dirs[0].T.astype(np.float64)
    return np.abs((n * v).sum(-1)) < eps


def test_page_gpu_decode_equals_the_compiled_player(page: Any, player: Any, compiled: Any,
                                                   decode: dict[str, Any]) -> None:
    from prt_torch.web.site import site_local

    assert page.page.evaluate("window.prt.info()")["decode"] == "gpu"
    c = player.order ** 2
    groups = decode["entry"]["groups"]
    for clip, frame, brdf, angle in (("wave", 3, "phong", 0.4), ("squat", 6, "lambert", 2.5), ("walk", 1, "ggx", 5.0)):
        local = site_local(player.character, clip, frame)
        for p in (player, compiled):
            p.set_brdf(brdf)
            p.light_angle = 0.0
            p.rotate_light(angle)
        state = compiled.pose(local)
        z = compiled.compiled.latent.run_unchecked({"pose": np.ascontiguousarray(state.features, np.float32)})[0]
        want = compiled.shade(state)[0].astype(np.float64)
        page.page.evaluate("s => window.prt.setState(s)", {**SKY, "brdf": brdf, "lightAngle": angle})
        got = np.reshape(page.page.evaluate("x => window.prt.radiance(x)", _inputs(state, z)), (-1, 3))
        zhat = rounded_latent(compiled, z, groups)
        bound = np.einsum("cvk,vc->vk", np.abs(shading_columns(player, state, c)), decode_bound(decode, zhat, c))
        atol = two_path_atol(SH_ROUNDINGS, float(np.abs(want).max())) + bound
        keep = ~grazing(state)
        err = np.abs(got - want)
        assert (err <= atol)[keep].all(), (clip, brdf, float((err - atol)[keep].max()), float(bound.max()))
        # the bound is a small fraction of the radiance: the test has teeth
        assert bound.max() < 0.02 * np.abs(want).max(), (clip, float(bound.max()))
        unshadowed = compiled.shade(state, visibility=np.broadcast_to(compiled.unshadowed, (1, len(got), c)))[0]
        assert np.abs(got - unshadowed)[keep].max() > 20 * atol.max(), "the decoded visibility casts no shadow"


def test_onnxruntime_web_latent_equals_onnxruntime(page: Any, player: Any, compiled: Any) -> None:
    from prt_torch.web.check import fp32_compute_session
    from prt_torch.web.site import site_local

    ch = player.character
    local = np.concatenate([site_local(ch, c, f) for c, f in (("walk", 1), ("wave", 4), ("stretch", 7))])
    feats = player.poser.features(local).astype(np.float32)
    got = page.page.evaluate("a => window.prt.latent(a[0], a[1])", [feats.reshape(-1).astype(float).tolist(),
                                                                    len(feats)])
    web = np.reshape(got["data"], got["dims"]).reshape(len(feats), -1)
    native = compiled.compiled.latent.run_unchecked({"pose": feats})[0].reshape(len(feats), -1)
    fp32 = fp32_compute_session(compiled.bundle.run.latent_graph_path)
    ref = native if fp32 is None else fp32.run(None, {"pose": feats})[0].reshape(len(feats), -1)
    rel = np.linalg.norm(web - ref, axis=1) / np.linalg.norm(ref, axis=1)
    assert rel.max() <= 1e-4, rel


def _radiance(ps: Any, state: dict[str, Any], inputs: dict[str, Any] | None) -> np.ndarray:
    ps.page.evaluate("s => window.prt.setState(s)", state)
    return np.asarray(ps.page.evaluate("x => window.prt.radiance(x)", inputs), np.float32).reshape(-1, 3)


def test_multirow_texel_layout_gives_the_same_radiance(browser: Any, site_url: str, page: Any, compiled: Any,
                                                      decode: dict[str, Any]) -> None:
    from prt_torch.web.site import site_local

    texels = decode["entry"]["texels"]
    width = 3 * texels  # 3 vertices per row of the basis texture, one per state row...: hundreds of rows
    state = compiled.pose(site_local(compiled.character, "wave", 5))
    z = compiled.compiled.latent.run_unchecked({"pose": np.ascontiguousarray(state.features, np.float32)})[0]
    settings = {**SKY, "brdf": "phong", "lightAngle": 1.1}
    wide = _radiance(page, settings, _inputs(state, z))
    ps = browser.open(site_url + f"?paused&texwidth={width}")
    try:
        assert ps.wait_ready(), ps.page.evaluate("window.prt.error")
        info = ps.page.evaluate("window.prt.info()")
        n_v = compiled.bundle.n_vertices
        assert info["basis"]["R"] == 3 and info["basis"]["height"] == -(-n_v // 3) > 1
        assert info["state"]["height"] > 1 and info["state"]["R"] < n_v
        narrow = _radiance(ps, settings, _inputs(state, z))
        assert ps.errors == []
    finally:
        ps.page.close()
    assert np.abs(wide).max() > 0
    assert_bitwise(narrow, wide, "the same shader arithmetic on the same texel values; the layout only moves the "
                                 "fetch addresses")
    bad = browser.open(site_url + f"?paused&texwidth={texels - 1}")  # a vertex's texels do not fit a row
    try:
        assert not bad.wait_ready()
        assert "texels per vertex do not fit a texture row" in bad.page.evaluate("window.prt.error")
    finally:
        bad.page.close()


def test_crowd_characters_keep_their_own_pose(browser: Any, site_url: str, player: Any, compiled: Any,
                                             decode: dict[str, Any]) -> None:
    """8 characters in one page (one instanced draw, the latent graph once with batch 8): character c's radiance is
    the compiled player's for its own pose, standing at its grid offset seen from the crowd camera's eye (view
    directions from ``eye - offset``), decoded from the z the page's latent graph returned for it (onnxruntime-web's
    float32 compute; its gap to native onnxruntime: the test above), within the same tolerance as one character's."""
    from prt_torch.web.site import site_local

    settings = {**SKY, "clip": "wave", "frame": 4, "brdf": "phong", "lightAngle": 0.3}
    for p in (player, compiled):
        p.set_brdf("phong")
        p.light_angle = 0.0
        p.rotate_light(0.3)
    c_count = player.order ** 2
    ps = browser.open(site_url + "?paused&characters=8")
    try:
        assert ps.wait_ready(), ps.page.evaluate("window.prt.error")
        assert ps.page.evaluate("window.prt.info()")["characters"] == 8
        _, stats = ps.frame(settings)
        crowd = ps.page.evaluate("window.prt.crowd()")
        got = {c: np.reshape(ps.page.evaluate("c => window.prt.radianceOf(c)", c), (-1, 3)) for c in (0, 5, 7)}
        assert ps.errors == []
    finally:
        ps.page.close()
    assert stats["characters"] == 8
    assert len({(q["clip"], q["frame"]) for q in crowd["poses"]}) == 8, "the characters share poses"
    eye = np.asarray(crowd["eye"], np.float64)
    offsets = np.reshape(crowd["offsets"], (-1, 3))
    assert np.linalg.norm(offsets[5] - offsets[0]) > 0
    for c, rad in got.items():
        q = crowd["poses"][c]
        state = compiled.poser(site_local(compiled.character, q["clip"], q["frame"]), eye - offsets[c])
        z = np.reshape(crowd["latent"]["data"], crowd["latent"]["dims"])[c:c + 1].astype(np.float32)
        want = shade_with_latent(compiled, state, z)
        zhat = rounded_latent(compiled, z, decode["entry"]["groups"])
        bound = np.einsum("cvk,vc->vk", np.abs(shading_columns(player, state, c_count)),
                          decode_bound(decode, zhat, c_count))
        atol = two_path_atol(SH_ROUNDINGS, float(np.abs(want).max())) + bound
        err = np.abs(rad - want)
        keep = ~grazing(state)
        assert (err <= atol)[keep].all(), (c, q, float((err - atol)[keep].max()))
    assert np.abs(got[5] - got[0]).max() > 20 * two_path_atol(SH_ROUNDINGS, float(np.abs(got[0]).max()))


def test_bench_web_prints_its_keys(tiny_run: Path, checked_site: tuple[Path, dict[str, Any]], chromium: str) -> None:
    from prt_torch.cli import main

    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        rc = main(["bench", "web", str(tiny_run), "--site", str(checked_site[0]), "--characters", "2", "--frames", "1",
                   "--json", "--chromium", chromium])
    assert rc == 0
    out = json.loads(buf.getvalue())
    assert out["characters"] == 2 and out["decode"] == "gpu"
    assert set(out["steps"]) >= {"posing", "inference", "draw"} and all(v >= 0 for v in out["steps"].values())
    assert out["fps"] > 0 and isinstance(out["renderer"], str) and isinstance(out["software_gl"], bool)


def test_visibility_graph_path_still_plays(browser: Any, site_url: str, page: Any, player: Any) -> None:
    """``?decode=cpu`` (what an export without ``latent.onnx`` plays: the whole visibility graph in onnxruntime-web,
    the coefficients uploaded per vertex) draws the frame the GPU decode draws, both the Python player's."""
    from prt_torch.scoring.images import ImageRenderer, player_camera
    from prt_torch.scoring.statistics import image_psnr
    from prt_torch.web.site import site_local

    settings = {**SKY, "clip": "squat", "frame": 5, "brdf": "phong", "lightAngle": 0.9}
    gpu, _ = page.frame(settings)
    ps = browser.open(site_url + "?paused&decode=cpu")
    try:
        assert ps.wait_ready(), ps.page.evaluate("window.prt.error")
        assert ps.page.evaluate("window.prt.info()")["decode"] == "visibility graph"
        cpu, _ = ps.frame(settings)
        assert ps.errors == []
    finally:
        ps.page.close()
    player.set_brdf("phong")
    player.light_angle = 0.0
    player.rotate_light(0.9)
    state = player.pose(site_local(player.character, "squat", 5))
    ref = player.render_frame(state, player.shade(state))
    ch = player.character
    with ImageRenderer(ch.rest_vertices, ch.faces, player_camera(ch, (480, 640))) as r:
        mask = r.mask(state.positions_vx3(0))
    assert image_psnr(gpu, ref, mask) >= 35.0 and image_psnr(cpu, ref, mask) >= 35.0

"""The shipping-path shading and image rule of ``prt_torch.scoring`` against independent references."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from prt_torch.brdf.rpo import builtin_rpo
from prt_torch.player.lighting import Lighting
from prt_torch.scoring.images import ImageRenderer, player_camera
from prt_torch.scoring.lighting import shipping_lights
from prt_torch.scoring.shading import ShippingShader
from prt_torch.scoring.statistics import image_psnr
from prt_torch.sh.basis import sh_basis
from prt_torch.sh.quadrature import random_rotations, sphere_quadrature
from prt_torch.sh.zonal import lobes_to_sh

ORDER = 4


def _scene(n_frames: int = 2, n_vertices: int = 6, seed: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    frames = random_rotations(n_frames * n_vertices, seed=seed).reshape(n_frames, n_vertices, 3, 3)
    positions = rng.normal(scale=0.3, size=(n_frames, n_vertices, 3))
    vis = rng.normal(scale=0.5, size=(n_frames, n_vertices, ORDER * ORDER))
    vis[..., 0] += 2.0
    return frames, positions, vis


def _brute_force(vis: np.ndarray, frames: np.ndarray, positions: np.ndarray, eye: np.ndarray, sh_world: np.ndarray,
                 rpo: object) -> np.ndarray:
    """``tint * sum_b (w_b . y(wo)) int L_local(s) U_b(s) V(s) ds`` by a sphere quadrature exact for the
    triple product (degree 3 (n - 1)); the local lighting is the world SH evaluated at ``F^T s`` (no SH
    rotation matrices, no product matrices)."""
    dirs, wts = sphere_quadrature(3 * (ORDER - 1))
    y = sh_basis(dirs, ORDER)  # (Q, C) local directions
    u_fun = y @ np.asarray(rpo.u, dtype=np.float64).T  # (Q, k)
    out = np.zeros(vis.shape[:2] + (3,))
    for f in range(vis.shape[0]):
        for v in range(vis.shape[1]):
            F = frames[f, v]
            world = dirs @ F  # rows: F^T s
            light = sh_basis(world, ORDER) @ sh_world  # (Q, 3)
            vfun = y @ vis[f, v]  # (Q,)
            wo = eye - positions[f, v]
            wo = F @ (wo / np.linalg.norm(wo))
            wb = sh_basis(wo[None], ORDER)[0] @ np.asarray(rpo.w, dtype=np.float64).T  # (k,)
            tri = np.einsum("q,qc,qk,q->kc", wts, light, u_fun, vfun)  # (k, 3)
            out[f, v] = np.asarray(rpo.tint, dtype=np.float64) * (wb @ tri)
    return out


@pytest.mark.parametrize("brdf", ["lambert", "phong"])
def test_exact_path_matches_brute_force_quadrature(brdf: str) -> None:
    frames, positions, vis = _scene()
    light = shipping_lights(ORDER, names=["sky"])["sky"]
    rpo = builtin_rpo(brdf, order=ORDER, k=8)
    eye = np.array([0.5, -4.0, 1.5])
    sh = ShippingShader({"sky": light}, {brdf: rpo}, eye, paths=("exact",), dtype=torch.float64)
    got = sh.shade_all({"truth": vis}, frames, positions)[("sky", brdf, "exact")]["truth"]
    want = _brute_force(vis, frames, positions, eye, light.sh, rpo)
    # the shader works in float64 but stores float32
    np.testing.assert_allclose(got, want, rtol=2e-5, atol=2e-5 * np.abs(want).max())


def test_lobes_equal_exact_for_three_lobe_lighting() -> None:
    frames, positions, vis = _scene(seed=3)
    dirs = np.array([[0.2, -0.5, 0.84], [-0.7, 0.3, 0.2], [0.1, 0.8, -0.5]])
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    coeffs = (0.7 ** np.arange(ORDER))[None, :, None] * np.array([[2.0, 1.8, 1.5], [0.4, 0.5, 0.7],
                                                                   [0.3, 0.2, 0.1]])[:, None, :]
    sh = lobes_to_sh(dirs, coeffs)
    light = Lighting(dirs.astype(np.float32), coeffs.astype(np.float32), sh, 0.0, "three lobes")
    rpos = {n: builtin_rpo(n, order=ORDER, k=8) for n in ("lambert", "phong")}
    sh_ = ShippingShader({"l": light}, rpos, np.array([0.0, -5.0, 1.0]), dtype=torch.float64)
    res = sh_.shade_all({"v": vis}, frames, positions)
    for b in rpos:
        ex, lo = res[("l", b, "exact")]["v"], res[("l", b, "lobes")]["v"]
        assert np.abs(lo - ex).max() <= 1e-4 * np.abs(ex).max(), b
        assert np.abs(ex).max() > 0.1


def test_chunking_does_not_change_the_result() -> None:
    frames, positions, vis = _scene(n_frames=5, n_vertices=4, seed=1)
    light = shipping_lights(ORDER, names=["sky"])
    rpos = {"phong": builtin_rpo("phong", order=ORDER, k=8)}
    eye = np.array([0.0, -3.0, 1.0])
    one = ShippingShader(light, rpos, eye, max_rows=4).shade_all({"v": vis}, frames, positions)
    big = ShippingShader(light, rpos, eye, max_rows=1 << 16).shade_all({"v": vis}, frames, positions)
    for k in one:
        np.testing.assert_allclose(one[k]["v"], big[k]["v"], rtol=1e-6, atol=1e-6)


@pytest.fixture(scope="module")
def small_character():  # noqa: ANN201
    from prt_torch.rig.builtin import make_character

    return make_character(0.1)


def test_image_psnr_identity_offset_and_mask(small_character) -> None:  # noqa: ANN001
    ch = small_character
    cam = player_camera(ch, (120, 160))
    pos = ch.rest_vertices
    with ImageRenderer(ch.rest_vertices, ch.faces, cam) as r:
        mask = r.mask(pos)
        h, w = mask.shape
        assert (h, w) == (120, 160)
        # the character is in view and the background is not in the mask
        assert 0.03 * h * w < mask.sum() < 0.8 * h * w
        assert not mask[0].any() and not mask[-1].any() and not mask[:, 0].any() and not mask[:, -1].any()
        rng = np.random.default_rng(0)
        col = rng.integers(30, 200, size=(ch.num_vertices, 3)).astype(np.uint8)
        a = r.render(pos, col)
        assert image_psnr(a, r.render(pos, col), mask) == float("inf")
        # a uniform colour offset d: MSE = (d / 255)^2 over the masked pixels -> PSNR = 20 log10(255 / d)
        d = 12
        b = r.render(pos, col + d)
        assert image_psnr(b, a, mask) == pytest.approx(20 * np.log10(255 / d), abs=0.35)
        # background pixels do not count: change the background only -> still identical over the mask
        r.renderer.plotter.set_background((0.9, 0.1, 0.1))
        c = r.render(pos, col)
        r.renderer.plotter.set_background(ImageRenderer.BACKGROUND)
        assert (c[~mask] != a[~mask]).any()
        assert image_psnr(c, a, mask) == float("inf")


def test_frame_images_share_the_truth_tone_map(small_character) -> None:  # noqa: ANN001
    ch = small_character
    cam = player_camera(ch, (90, 120))
    rng = np.random.default_rng(1)
    truth = rng.uniform(0.2, 1.0, size=(ch.num_vertices, 3)).astype(np.float32)
    with ImageRenderer(ch.rest_vertices, ch.faces, cam) as r:
        fi = r.frame_images(ch.rest_vertices, {"truth": truth, "same": truth.copy(), "dark": 0.5 * truth}, "truth")
    assert fi.sse["same"][0] == 0.0 and fi.sse["truth"][0] == 0.0
    assert fi.sse["dark"][0] > 0 and fi.sse["dark"][1] == 3 * int(fi.mask.sum())

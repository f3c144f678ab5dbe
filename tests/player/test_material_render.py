"""A character's material in the Python player: the base-colour texture per pixel (against an independent
ray-traced reference of the exact rule ``tonemap(interp(L) * factor * texture(interp(uv)))``), a constant texture
equal to the factor alone, the material's Cook-Torrance RPO chosen by default and cached in the run, and the
built-in character's default material."""

from __future__ import annotations

import shutil
import sys
from pathlib import Path

import numpy as np
import pytest
from scipy import ndimage

from prt_torch.errors import PrtError
from prt_torch.player import Player
from prt_torch.rig.material import DEFAULT_MATERIAL, Material, srgb_to_linear
from tests.textured import textured_copy
from tests.tolerance import assert_bitwise

SIZE = (240, 320)  # (H, W) of the test renders
BACKGROUND = np.array([0.08, 0.08, 0.1])  # MeshRenderer's default


@pytest.fixture(scope="module")
def textured_run(tiny_run: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A copy of the tiny run whose character carries a checker-textured material (roughness 0.4); the material
    is not part of the character hash, so the export still verifies."""
    return textured_copy(tiny_run, tmp_path_factory.mktemp("material") / "run",
                         ignore=("dataset.zarr", "compare", "report", "*.mp4"))


def ray_traced(player: Player, positions: np.ndarray, radiance: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(image (H, W, 3) uint8, hit mask (H, W))``: the exact per-pixel rule, independently of VTK: a pinhole
    camera (the player's eye and target, z up, 30 degree vertical view angle, pixel centres), Embree closest hits,
    perspective-correct barycentrics of the hit, linear radiance and UVs interpolated, the texture sampled
    bilinearly, times the factor, then the player's tone map."""
    from prt_torch.bake.embree import RayScene
    from prt_torch.rig.material import sample_texture

    ch = player.character
    h, w = player.window_size
    eye, target = player.eye.astype(np.float64), player.center.astype(np.float64)
    fwd = (target - eye) / np.linalg.norm(target - eye)
    right = np.cross(fwd, [0.0, 0.0, 1.0])
    right /= np.linalg.norm(right)
    up = np.cross(right, fwd)
    th = np.tan(np.radians(30.0) / 2)
    col, row = np.meshgrid(np.arange(w), np.arange(h))
    d = (fwd + ((2 * (col + 0.5) / w - 1) * th * w / h)[..., None] * right
         + ((1 - 2 * (row + 0.5) / h) * th)[..., None] * up).reshape(-1, 3)
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    hits = RayScene(positions.astype(np.float32), ch.faces).intersect(
        np.broadcast_to(eye, d.shape).astype(np.float32), d.astype(np.float32))
    hit = hits.prim >= 0
    tri = hits.prim[hit]
    bu, bv = hits.u[hit].astype(np.float64), hits.v[hit].astype(np.float64)
    bary = np.stack([1 - bu - bv, bu, bv], 1)
    L = np.einsum("nk,nkc->nc", bary, radiance[ch.faces[tri]])
    m = ch.material
    base = np.asarray(m.base_color[:3])
    if m.texture is not None:
        base = sample_texture(m.texture, np.einsum("nk,nkc->nc", bary, ch.uv[tri])) * base
    img = np.empty((h * w, 3), np.uint8)
    img[:] = (BACKGROUND * 255 + 0.5).astype(np.uint8)
    img[hit] = player.exposure(L * base)
    return img.reshape(h, w, 3), hit.reshape(h, w)


def psnr(a: np.ndarray, b: np.ndarray, mask: np.ndarray) -> float:
    d = (a.astype(np.float64) - b.astype(np.float64))[mask]
    return float(10 * np.log10(255.0**2 / max(float(np.mean(d**2)), 1e-12)))


def _frame(p: Player, clip: str = "wave", frame: int = 5):
    state, rad = p.compute(p.clip_locals(clip)[frame:frame + 1])
    return state, rad


def test_per_pixel_texture_matches_ray_traced_reference(textured_run: Path) -> None:
    from prt_torch.player.render import MeshRenderer

    p = Player(textured_run, threads=1, graph="split", window_size=SIZE)
    try:
        state, rad = _frame(p)
        img = p.render_frame(state, rad)
        ref, hit = ray_traced(p, state.positions_vx3(0), rad[0])
        # the per-vertex average base colour (what the player showed before) on the same frame
        with MeshRenderer(p.character.rest_vertices, p.character.faces, window_size=(SIZE[1], SIZE[0])) as mr:
            mr.set_camera(p.eye, p.center)
            mr.update(state.positions_vx3(0), p.colors(rad[0]))
            averaged = mr.render()
    finally:
        p.close()
    inner = ndimage.binary_erosion(hit, iterations=2)  # the silhouette keeps anti-aliased per-vertex colours
    assert inner.sum() > 3000 and ref[inner].std() > 20
    got, old = psnr(img, ref, inner), psnr(averaged, ref, inner)
    # measured: identical inside the character (infinite PSNR; per-vertex average 22.9 dB), 34.9 dB over every
    # pixel a ray hits (the anti-aliased silhouette ring); a flipped v or a wrong triangle drops it below 20 dB
    assert got >= 45.0, (got, old)
    assert old < 30.0  # the checker really is sharper than the vertices can show: the test can tell them apart
    assert psnr(img, ref, hit) >= 28.0


def test_constant_texture_equals_the_factor_alone(textured_run: Path) -> None:
    """A uniform texture ``s`` with factor ``f`` renders as the factor ``f * linear(s)`` alone: per pixel exactly
    (the ray-traced rule of the untextured material), and within the Gouraud-interpolation difference of the
    untextured player path (which interpolates tone-mapped vertex colours instead of linear radiance)."""
    s = np.array([200, 120, 60], np.uint8)
    f = (0.9, 0.8, 1.0, 1.0)
    images, refs = [], []
    tm = None
    for textured in (True, False):
        # the whole lighting on the SH path (peaks=0): the Gouraud bound below was measured for smooth light; the
        # sun's crisp peak shadow varies faster across a triangle than per-vertex colours can follow
        p = Player(textured_run, threads=1, graph="split", window_size=SIZE, exposure=tm, peaks=0)
        ch = p.character
        if textured:
            ch.material = Material("flat", f, 0.0, 0.4, np.broadcast_to(s, (4, 4, 3)).copy())
        else:
            ch.uv = None
            ch.material = Material("flat", (*(np.asarray(f[:3]) * srgb_to_linear(s / 255.0)), 1.0), 0.0, 0.4)
        try:
            state, rad = _frame(p)
            images.append(p.render_frame(state, rad))
            tm = p.exposure
            ref, hit = ray_traced(p, state.positions_vx3(0), rad[0])
            refs.append(ref)
        finally:
            p.close()
    inner = ndimage.binary_erosion(hit, iterations=2)
    assert inner.sum() > 3000 and images[1][inner].std() > 5
    exact = np.abs(images[0].astype(int) - refs[1].astype(int)).max(-1)[inner]
    assert exact.max() <= 1, exact.max()  # float32 texture product vs the factor: one 8-bit step at most
    gouraud = np.abs(images[0].astype(int) - images[1].astype(int)).max(-1)[inner]
    # measured: mean 1.05, max 17 levels (where the light changes fast across a triangle)
    assert gouraud.mean() < 2.0 and np.percentile(gouraud, 99) <= 12, (gouraud.mean(), np.percentile(gouraud, 99))


def test_material_rpo_is_cook_torrance_and_cached_in_the_run(textured_run: Path,
                                                            monkeypatch: pytest.MonkeyPatch) -> None:
    import prt_torch.brdf.rpo as rpo_mod
    from prt_torch.brdf import CookTorrance, build_rpo
    from prt_torch.rig.material import material_rpo_key
    from prt_torch.rundir import RunDir

    run = RunDir(textured_run)
    p = Player(textured_run, threads=1, graph="split", window_size=SIZE)
    try:
        assert p.rpo.name == "material"  # the default of a character with its own material
        names = [p.next_brdf() for _ in range(5)]
        assert "material" in names and p.rpo.name == names[-1]
        p.set_brdf("material")
        M = p.rpo.M.copy()
    finally:
        p.close()
    cached = run.material_rpo_path(material_rpo_key(run.character().material, 4, 8))
    assert cached.is_file()
    # the independent definition: GGX with roughness 0.4, dielectric f0 0.04, 1/4 specular, 3/4 Lambert
    ref = build_rpo(CookTorrance(roughness=0.4, f0=0.04, kd=0.75, ks=0.25), order=4, k=8)
    np.testing.assert_allclose(M[:ref.k], ref.M, rtol=1e-5, atol=1e-6)

    def no_build(*args, **kwargs):
        raise AssertionError("the cached material RPO was built again")

    monkeypatch.setattr(rpo_mod, "build_rpo", no_build)
    p = Player(textured_run, threads=1, graph="split", window_size=SIZE, brdf="material")
    try:
        assert_bitwise(p.rpo.M, M, why='the cached RPO read back')
    finally:
        p.close()


def test_builtin_character_default_material(tiny_run: Path, tmp_path: Path) -> None:
    """The built-in character has no material of its own: DEFAULT_MATERIAL (white, roughness 0.5, dielectric)
    leaves its colours and its default BRDF as they were; ``--brdf material`` plays that material's RPO."""
    from prt_torch.brdf import CookTorrance, build_rpo
    from prt_torch.player.material import brdf_names, select_rpo, surface_texture, vertex_base_color
    from prt_torch.rig.material import character_material

    dst = tmp_path / "run"
    shutil.copytree(tiny_run, dst, ignore=shutil.ignore_patterns("dataset.zarr", "compare", "report", "*.mp4"))
    p = Player(dst, threads=1, graph="split", window_size=SIZE)
    try:
        assert character_material(p.character) is DEFAULT_MATERIAL
        assert vertex_base_color(p.character) is None and surface_texture(p.character) is None
        assert p.rpo.name == p.bundle.brdf_names[0] and brdf_names(p.bundle)[-1] == "material"
        state, rad = _frame(p)
        assert_bitwise(p.colors(rad[0]), p.exposure(rad[0]),
                       why='a white base colour multiplies by 1.0, which is exact')  # white: unchanged
        mat = select_rpo(p.bundle, "material")
        with pytest.raises(PrtError, match="unknown BRDF 'nope'.*'material'"):
            select_rpo(p.bundle, "nope")
    finally:
        p.close()
    ref = build_rpo(CookTorrance(roughness=0.5, f0=0.04, kd=0.75, ks=0.25), order=4, k=8)
    np.testing.assert_allclose(mat.M[:ref.k], ref.M, rtol=1e-5, atol=1e-6)


def test_material_rpo_without_scikit_learn_is_one_line(textured_run: Path, tmp_path: Path,
                                                        monkeypatch: pytest.MonkeyPatch) -> None:
    from prt_torch.player.material import select_rpo
    from prt_torch.rig.material import material_rpo_file

    monkeypatch.setitem(sys.modules, "sklearn", None)  # a player-only install: import sklearn fails
    with pytest.raises(PrtError, match=r"scikit-learn.*prt-torch\[export\]") as exc:
        material_rpo_file(Material(roughness=0.77), 4, 8, cache_dir=tmp_path)
    assert "\n" not in str(exc.value)
    assert material_rpo_file(Material(roughness=0.77), 4, 8, cache_dir=tmp_path, build=False) is None
    p = Player(textured_run, threads=1, graph="split", window_size=SIZE, brdf="lambert")
    try:  # a material whose RPO is not cached: explicit `material` fails in one line, the default falls back
        p.character.material = Material("uncached", roughness=0.77)
        with pytest.raises(PrtError, match="scikit-learn"):
            select_rpo(p.bundle, "material")
        with pytest.warns(UserWarning, match="scikit-learn"):
            assert select_rpo(p.bundle).name == p.bundle.brdf_names[0]
    finally:
        p.close()


def test_play_command_lists_and_plays_the_material(textured_run: Path, tmp_path: Path,
                                                   capsys: pytest.CaptureFixture[str]) -> None:
    from prt_torch.cli import main

    rc = main(["play", str(textured_run), "--clip", "wave", "--png", str(tmp_path / "x"), "--brdf", "nope",
               "--max-frames", "1"])
    err = capsys.readouterr().err
    assert rc != 0 and "unknown BRDF 'nope'" in err and "'material'" in err
    rc = main(["play", str(textured_run), "--clip", "wave", "--png", str(tmp_path / "png"), "--brdf", "material",
               "--max-frames", "1", "--size", "120x160", "--threads", "1"])
    assert rc == 0 and (tmp_path / "png" / "frame_00000.png").is_file()

"""Character materials: glTF pbrMetallicRoughness + TEXCOORD_0 loading, texture sampling, the per-vertex base colour
the Python player multiplies in, persistence in character.npz, and the material's Cook-Torrance BRDF."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy import ndimage

from prt_torch.errors import PrtError
from prt_torch.rig.material import (
    DEFAULT_MATERIAL,
    Material,
    character_material,
    material_brdf,
    sample_texture,
    srgb_to_linear,
)
from tests.tolerance import assert_bitwise


def test_srgb_curve_closed_form() -> None:
    x = np.array([0.0, 0.04045, 0.5, 1.0])
    ref = [0.0, 0.04045 / 12.92, ((0.5 + 0.055) / 1.055) ** 2.4, 1.0]
    np.testing.assert_allclose(srgb_to_linear(x), ref, rtol=1e-12)


def test_bilinear_wrapped_sampling_equals_scipy() -> None:
    rng = np.random.default_rng(0)
    tex = rng.integers(0, 256, (7, 11, 3), dtype=np.uint8)
    uv = rng.uniform(-1.5, 2.5, (200, 2))
    lin = srgb_to_linear(tex / 255.0)
    # texel centres at half-integers: pixel coordinates (row, col) = (v H - 0.5, u W - 0.5), wrapped
    rows, cols = uv[:, 1] * 7 - 0.5, uv[:, 0] * 11 - 0.5
    ref = np.stack([ndimage.map_coordinates(lin[..., c], [rows, cols], order=1, mode="grid-wrap") for c in range(3)], 1)
    np.testing.assert_allclose(sample_texture(tex, uv), ref, atol=1e-6)


def test_material_validation_is_one_line() -> None:
    with pytest.raises(PrtError, match="roughness"):
        Material(roughness=1.5)
    with pytest.raises(PrtError, match="texture"):
        Material(texture=np.zeros((4, 4), np.uint8))


def test_material_brdf_follows_roughness_and_metallic() -> None:
    b = material_brdf(Material(roughness=0.6, metallic=0.0))
    assert b.alpha == pytest.approx(0.36) and b.kd + b.ks == pytest.approx(1.0) and b.f0 == pytest.approx(0.04)
    metal = material_brdf(Material(roughness=0.3, metallic=1.0))
    assert metal.kd == pytest.approx(0.0) and metal.f0 == pytest.approx(1.0)
    assert material_brdf(Material(roughness=0.0)).roughness == pytest.approx(0.02)  # clamped to the BRDF's range


def test_builtin_character_default_material_and_npz_round_trip(tmp_path: Path) -> None:
    from prt_torch.player.material import vertex_base_color
    from prt_torch.rig.builtin import make_character
    from prt_torch.rig.character import Character

    ch = make_character(density=0.1)
    assert character_material(ch) is DEFAULT_MATERIAL and vertex_base_color(ch) is None
    h = ch.content_hash()
    ch.save(tmp_path / "plain.npz")  # a file without material keys (the old format) still loads
    assert Character.load(tmp_path / "plain.npz").material is None
    tex = np.arange(2 * 3 * 4, dtype=np.uint8).reshape(2, 3, 4)
    ch.uv = np.random.default_rng(1).uniform(0, 1, (len(ch.faces), 3, 2)).astype(np.float32)
    ch.material = Material("m", (0.5, 0.25, 1.0, 1.0), 0.2, 0.7, tex)
    ch.save(tmp_path / "mat.npz")
    back = Character.load(tmp_path / "mat.npz")
    assert back.content_hash() == h  # the material is not part of the character's identity
    assert back.material.summary() == ch.material.summary()
    assert_bitwise(back.material.texture, tex, why='npz round trip')
    assert_bitwise(back.uv, ch.uv, why='npz round trip')


def test_constant_base_colour_is_the_factor() -> None:
    from prt_torch.player.material import vertex_base_color
    from prt_torch.rig.builtin import make_character

    ch = make_character(density=0.1)
    ch.material = Material("red", (0.8, 0.1, 0.2, 1.0))
    base = vertex_base_color(ch)
    np.testing.assert_allclose(base, np.broadcast_to([0.8, 0.1, 0.2], base.shape), rtol=1e-6)


def test_fox_keeps_its_texture(shared_data: Path) -> None:
    from prt_torch.player.material import vertex_base_color
    from prt_torch.rig.gltf import load_gltf

    ch = load_gltf(shared_data / "characters" / "Fox.glb")
    m = ch.material
    assert m is not None and m.texture is not None and m.texture.shape[2] == 3 and 0 < m.roughness < 1
    assert ch.uv.shape == (len(ch.faces), 3, 2) and np.isfinite(ch.uv).all()
    base = vertex_base_color(ch)
    assert base.shape == (ch.num_vertices, 3)
    r, g, b = np.median(base, axis=0)
    assert r > g > b, "the fox is orange"  # not the flat grey it used to be
    assert base.std(0).max() > 0.05  # and not one flat colour either


def test_material_rpo_key_is_the_brdf_not_the_colour(tmp_path: Path) -> None:
    from prt_torch.rig.material import material_rpo_key
    from prt_torch.rundir import RunDir

    k = material_rpo_key(Material(roughness=0.4), 4, 8)
    assert k == material_rpo_key(Material("other", (0.2, 0.5, 0.1, 1.0), roughness=0.4), 4, 8)  # colour: no RPO
    assert len({k, material_rpo_key(Material(roughness=0.41), 4, 8), material_rpo_key(Material(roughness=0.4,
                metallic=1.0), 4, 8), material_rpo_key(Material(roughness=0.4), 3, 8),
                material_rpo_key(Material(roughness=0.4), 4, 6)}) == 5
    run = RunDir(tmp_path / "run")
    assert run.material_rpo_path(k).parent == run.rpo_dir and k in run.material_rpo_path(k).name
    with pytest.raises(PrtError, match="bad material RPO key"):
        run.material_rpo_path("../x")

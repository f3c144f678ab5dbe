"""``prt play`` on a glTF character with a material (``gltf_run``: the synthetic figure, base colour
``(0.9, 0.45, 0.25)``): every ``--renderer``, the floor (``--ground``) and a ``--scene``.

The floor's radiance is its own (albedo times the lighting through its visibility); the character's is multiplied by
its base colour. Multiplying the floor by the character's per-vertex base colour crashed ``--ground`` with a
broadcast error (floor vertices x 3 against character vertices x 3). References: the material's factor as written
into the glTF file (not the player's ``vertex_base_color``), the scene's one tone map applied to each part's
radiance, and the rendered pixels' colour: orange on the character, not on the floor or a white character.
"""

from __future__ import annotations

from pathlib import Path

import imageio.v3 as iio
import numpy as np
import pytest

from prt_torch.cli import main
from tests.rig.gltf_synth import FIGURE_MATERIAL

SIZE = "60x80"


def _play(argv: list[str], capsys: pytest.CaptureFixture[str]) -> str:
    capsys.readouterr()
    rc = main(["play", *argv])
    err = capsys.readouterr().err
    assert rc == 0, err
    assert "error" not in err and "Traceback" not in err, err
    return err


def _frame(png_dir: Path) -> np.ndarray:
    files = sorted(png_dir.glob("frame_*.png"))
    assert len(files) == 1, files
    img = iio.imread(files[0]).astype(np.float64)
    assert img.shape == (60, 80, 3)
    return img


def _lit(img: np.ndarray) -> np.ndarray:
    """The pixels that are not the renderer's background (the top-left pixel of these framings)."""
    return np.abs(img - img[0, 0]).sum(-1) > 6


@pytest.mark.parametrize("renderer", ["onnx", "sg", "s001", "posespace", "transfer"])
def test_every_renderer_plays_a_gltf_character_in_its_base_colour(gltf_run: Path, tmp_path: Path, renderer: str,
                                                                   capsys: pytest.CaptureFixture[str]) -> None:
    """Default BRDF included (the character's own material where the renderer shades it, else the run's first
    catalogue BRDF: ``sg`` shades catalogue BRDFs only): one frame written, and the character shows its orange base
    colour (red > green > blue, red at least 1.3 x blue; a white material does not:
    :func:`test_white_material_is_not_orange`)."""
    extra = ["--vct-resolution", "24"] if renderer == "sg" else []
    _play([str(gltf_run), "--clip", "twist", "--renderer", renderer, "--png", str(tmp_path / "png"),
           "--max-frames", "1", "--size", SIZE, "--timings", str(tmp_path / "t.json"), *extra], capsys)
    img = _frame(tmp_path / "png")
    mask = _lit(img)
    assert 0.05 < mask.mean() < 0.6, mask.mean()
    r, g, b = img[mask].mean(0)
    assert r > g > b and r > 1.3 * b, (r, g, b)


def test_white_material_is_not_orange(gltf_run: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """The control: the same run with the character's base colour set to white (a material is not part of the
    character hash, so the export still verifies) renders in the sky's own slightly blue light, not orange; the
    orange one orange (both diffuse, same frame)."""
    import shutil

    from prt_torch.rig.material import Material
    from prt_torch.rundir import RunDir

    white = tmp_path / "white"
    shutil.copytree(gltf_run, white, ignore=shutil.ignore_patterns("dataset.zarr", "*.json.tmp*"))
    ch = RunDir(white).character()
    ch.material = Material("white", (1.0, 1.0, 1.0, 1.0), 0.0, 0.6)
    ch.save(RunDir(white).character_path)
    means = {}
    for run in (gltf_run, white):
        out = tmp_path / f"png_{run.name}"
        _play([str(run), "--clip", "twist", "--brdf", "lambert", "--png", str(out), "--max-frames", "1",
               "--size", SIZE, "--timings", str(tmp_path / "t.json")], capsys)
        img = _frame(out)
        means[run] = img[_lit(img)].mean(0)
    grey, orange = means[white], means[gltf_run]
    assert grey[0] < 1.05 * grey[2], grey
    assert orange[0] > orange[1] > orange[2] and orange[0] > 1.3 * orange[2], orange


def test_ground_floor_has_its_own_colour_and_the_character_its_base_colour(gltf_run: Path) -> None:
    """``ScenePlayer.colors``: the floor is the tone map of its own radiance, the character the tone map of its
    radiance times the material's factor (from the glTF file), under the one tone map of the frame."""
    from prt_torch.player.scene import ScenePlayer
    from prt_torch.player.tonemap import auto_tonemap

    sp = ScenePlayer(gltf_run, ground=True, clip="twist", window_size=(60, 80))
    try:
        f = sp.compute(0)
        assert f.ground_radiance is not None and len(f.ground_radiance) != sp.primary.character.num_vertices
        cols, gcol = sp.colors(f)
        factor = np.asarray(FIGURE_MATERIAL[0][:3], np.float32)
        body = f.radiance[0][0] * factor
        want = auto_tonemap(np.concatenate([body, f.ground_radiance]))
        assert (sp.exposure.exposure, sp.exposure.white) == pytest.approx((want.exposure, want.white))
        np.testing.assert_array_equal(gcol, want(f.ground_radiance))
        np.testing.assert_array_equal(cols[0], want(body))
        img = sp.render(f)
    finally:
        sp.close()
    assert img.shape == (60, 80, 3)


def test_prt_play_ground_on_a_gltf_character(gltf_run: Path, tmp_path: Path,
                                             capsys: pytest.CaptureFixture[str]) -> None:
    """The command that crashed: ``prt play RUN --clip NAME --ground``. The floor (the image's bottom rows, in front
    of the character) has the sky's slightly blue light on its grey albedo, not the character's orange; the
    character is orange."""
    _play([str(gltf_run), "--clip", "twist", "--ground", "--png", str(tmp_path / "png"), "--max-frames", "1",
           "--size", SIZE, "--timings", str(tmp_path / "t.json")], capsys)
    img = _frame(tmp_path / "png")
    floor = img[-6:].reshape(-1, 3)
    assert _lit(img)[-6:].all()  # the floor fills the bottom of the frame
    fr, _, fb = floor.mean(0)
    assert fr < 1.05 * fb, floor.mean(0)
    upper = img[:30]
    mask = _lit(upper) & (np.ptp(upper, axis=-1) > 0.25 * upper.mean(-1))  # the saturated (character) pixels
    r, g, b = upper[mask].mean(0)
    assert mask.sum() > 20 and r > g > b and r > 1.3 * b, (mask.sum(), r, g, b)


def test_prt_play_scene_of_two_gltf_characters(gltf_run: Path, tmp_path: Path,
                                               capsys: pytest.CaptureFixture[str]) -> None:
    """``--scene``: two of the run's characters on a floor (cast shadows between them through the SHEXP graph)."""
    scene = tmp_path / "scene.yaml"
    scene.write_text("scene:\n  ground: {resolution: 16}\n  characters:\n"
                     "    - {clip: twist}\n    - {clip: bend, offset: [1.6, 0.8, 0.0], yaw_deg: 30.0}\n")
    err = _play([str(gltf_run), "--scene", str(scene), "--png", str(tmp_path / "png"), "--max-frames", "1",
                 "--size", SIZE, "--timings", str(tmp_path / "t.json")], capsys)
    assert "2 character(s), a floor" in err
    _frame(tmp_path / "png")


@pytest.mark.parametrize("renderer", ["sg", "s001", "posespace", "transfer"])
def test_ground_with_another_renderer_is_refused(gltf_run: Path, tmp_path: Path, renderer: str,
                                                 capsys: pytest.CaptureFixture[str]) -> None:
    """The floor is shaded through the learned models' players only: another ``--renderer`` is one line, not
    silently ignored; nothing is written."""
    capsys.readouterr()
    rc = main(["play", str(gltf_run), "--clip", "twist", "--ground", "--renderer", renderer, "--png",
               str(tmp_path / "png")])
    err = capsys.readouterr().err
    assert rc == 2 and err == (f"error: --ground/--scene play the run's learned models (--renderer onnx), not "
                               f"--renderer {renderer}\n")
    assert not (tmp_path / "png").exists()

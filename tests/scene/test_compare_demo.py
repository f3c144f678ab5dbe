"""``prt compare`` and ``prt demo`` with a floor: compare.json's ``ground`` and ``scene`` sections (whole-scene Embree
truth) and the demo's third comparison row and scene video; the CLI's one-line errors for a bad scene."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
import yaml

from prt_torch.scene.config import scene_from_dict
from tests.export.pipeline import TINY_CONFIG
from tests.scene.fixtures import scene_run, scene_run_copy  # noqa: F401


def test_compare_reports_ground_and_in_scene(scene_run: Path) -> None:  # noqa: F811
    from prt_torch.compare.run import run_compare
    from prt_torch.rundir import RunDir

    res = run_compare(scene_run, methods=["learned_mlp"], max_frames=2, image_frames=1, reference_frames=0,
                      scene=scene_from_dict({"ground": {"resolution": 24}}))
    g = res["ground"]
    assert set(g) >= {"psnr_image", "radiance_rel_rmse", "vis_rel_err"}
    # the floor's soft shadow by SHEXP is close to the whole-scene truth (tiny 1.2k-vertex character, 48 spheres)
    assert g["vis_rel_err"] < 0.1 and g["radiance_rel_rmse"] < 0.1 and g["psnr_image"] > 25.0
    (c,) = res["scene"]["characters"]
    # composing the floor as a half-space brings the learned visibility much closer to the whole-scene truth
    assert c["in_scene"]["vis_rel_err"] < 0.7 * c["self_only"]["vis_rel_err"]
    assert c["in_scene"]["radiance_rel_rmse"] < c["self_only"]["radiance_rel_rmse"]
    run = RunDir(scene_run)
    saved = json.loads(run.compare_json.read_text())
    assert saved["ground"]["vis_rel_err"] == pytest.approx(g["vis_rel_err"])
    assert "ground (SHEXP)" in run.compare_table.read_text() and run.compare_ground.is_file()


def test_demo_with_floor(tmp_path_factory: pytest.TempPathFactory) -> None:
    import imageio.v2 as iio

    from prt_torch.cli import main

    base = tmp_path_factory.getbasetemp()
    run_dir = scene_run_copy(base, "scene_demo_run")
    cfg = base / "scene_demo.yaml"
    cfg.write_text(yaml.safe_dump({**TINY_CONFIG, "run_dir": str(run_dir),
                                   "scene": {"ground": {"resolution": 16}}}))
    assert main(["demo", "--config", str(cfg), "--frames", "3", "--size", "120x160", "--brdf", "phong"]) == 0
    png = iio.imread(run_dir / "comparison.png")
    assert png.shape == (3 * 120, 4 * 160, 3)  # a third row (the scene); 4 columns: reference | truth | model | diff
    _, truth, model, diff = np.split(png[240:].astype(float), 4, axis=1)  # a blank under the reference column
    assert np.abs(truth - model).mean() < 0.25 * truth.mean() and diff.mean() < truth.mean()
    frames = [f for f in iio.get_reader(run_dir / "heldout.mp4")]  # noqa: C416  (list() asks len(): inf)
    assert len(frames) == 3
    bg = np.round(np.array([0.08, 0.08, 0.1]) * 255)
    assert (np.abs(frames[0][-20:].astype(float) - bg).max(-1) > 8).mean() > 0.9  # the floor
    m = json.loads((run_dir / "demo_metrics.json").read_text())["scene"]
    assert m["vis_rel_err_in_scene"] < m["vis_rel_err_self_only"]
    assert json.loads((run_dir / "scene.json").read_text())["ground"]["resolution"] == 16
    shutil.rmtree(run_dir)


@pytest.mark.parametrize("text, key", [("scene: {ground: {resolution: 0}}", "resolution"),
                                       ("scene: {characters: [{clip: walk, offset: [1, 2]}]}", "offset"),
                                       ("scene: [1, 2]", "mapping")])
def test_play_bad_scene_is_one_line_error(scene_run: Path, tmp_path: Path, capsys, text: str, key: str  # noqa: F811
                                          ) -> None:
    from prt_torch.cli import main

    bad = tmp_path / "bad_scene.yaml"
    bad.write_text(text + "\n")
    rc = main(["play", str(scene_run), "--clip", "wave", "--scene", str(bad), "--png", str(tmp_path / "png")])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and key in err[0]


def test_compare_two_characters_per_character(scene_run: Path) -> None:  # noqa: F811
    from prt_torch.compare.run import run_compare

    scene = scene_from_dict({"ground": {"resolution": 16},
                             "characters": [{"clip": "wave"}, {"clip": "squat", "offset": [-0.9, 0.9, 0.0]}]})
    res = run_compare(scene_run, methods=["learned_mlp"], max_frames=1, image_frames=1, reference_frames=0,
                      scene=scene)
    chars = res["scene"]["characters"]
    assert len(chars) == 2 and res["scene"]["fps"] > 0
    for c in chars:  # floor half-space and the other character's SHEXP bring each closer to the whole-scene truth
        assert c["in_scene"]["vis_rel_err"] < c["self_only"]["vis_rel_err"]
        assert c["in_scene"]["radiance_rel_rmse"] < c["self_only"]["radiance_rel_rmse"]

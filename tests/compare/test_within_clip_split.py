"""A run whose held-out split is a frame range of a training clip (issue 27 item 0: ``heldout_clips: [{clip: walk,
frames: "4:", name: walk_tail}]``): ``prt compare``'s default methods, ``shexp`` explicitly, ``--clip walk_tail``
and ``prt play --clip walk_tail`` all pose those frames by the one clip-name rule
(:func:`prt_torch.rig.load.clip_by_name`), checked against an independent posing of the source clip and against
the positions the bake traced."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import yaml

from prt_torch.cli import main
from prt_torch.rundir import RunDir
from tests.tolerance import assert_bitwise, two_path_atol

SOURCE, START, NAME = "walk", 4, "walk_tail"
CONFIG = {
    "name": "within_clip",
    "character": {"source": "builtin", "density": 0.1, "fps": 6,
                  "train_clips": [{"clip": SOURCE, "frames": f":{START}"}, "squat"],
                  "heldout_clips": [{"clip": SOURCE, "frames": f"{START}:", "name": NAME}],
                  "random_poses": 0, "seed": 0},
    "bake": {"order": 3, "n_rays": 32, "frames_per_task": 8, "workers": 1, "seed": 0},
    "train": {"kinds": ["linear"], "default_kind": "linear", "alphas": [1.0], "folds": 2, "cv_iter": 10,
              "max_iter": 30, "seed": 0},
}


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The within-clip run, baked, trained and exported (with its sphere set, so ``shexp`` is a default method)."""
    pytest.importorskip("embreex")
    pytest.importorskip("onnxruntime")
    base = tmp_path_factory.mktemp("within_clip")
    run = base / "run"
    cfg = base / "within_clip.yaml"
    cfg.write_text(yaml.safe_dump({**CONFIG, "run_dir": str(run)}))
    assert main(["bake", str(cfg), "--no-progress"]) == 0
    assert main(["train", str(cfg)]) == 0
    assert main(["export", str(run)]) == 0
    return run


def source_poses(run: Path) -> tuple[np.ndarray, np.ndarray]:
    """Independent of compare: the dataset's held-out rows and the skinning matrices of their frames, the source
    clip posed at the config's rate (the builtin character's clips are at ``character.fps``) and indexed by hand."""
    rd = RunDir(run)
    ds, ch = rd.dataset(), rd.character()
    rows = ds.split_rows("heldout")
    assert [ds.clip_names[i] for i in ds.clip_id[rows]] == [NAME] * len(rows)
    n = ch.clips[SOURCE].num_frames
    np.testing.assert_array_equal(ds.frame_index[rows], np.arange(START, n))
    return rows, ch.pose(ch.clips[SOURCE]).skin[START:]


def skin_atol(n_joints: int) -> float:
    """Two float64 posings of one frame (forward kinematics down a chain of at most ``n_joints`` 4x4 products,
    entries below 4 in size: rotations and metre-scale translations)."""
    return two_path_atol(4 * n_joints, 4.0, np.float64)


def position_atol(positions: np.ndarray, n_joints: int) -> float:
    """Two float32 skinnings of one frame (a weighted sum over the joints of 3-term products per coordinate)."""
    return two_path_atol(4 * n_joints, float(np.abs(positions).max()) + 1.0)


def test_default_methods_accept_a_within_clip_split(run_dir: Path) -> None:
    assert main(["compare", str(run_dir), "--frames", "2", "--image-frames", "1", "--reference-frames", "1",
                 "--reference-rays", "16"]) == 0
    r = json.loads(RunDir(run_dir).compare_json.read_text())
    assert r["clips"] == [NAME] and r["frames"] == 2
    assert "shexp" in r["methods"] and "learned_linear" in r["methods"]
    assert r["strip_frame"]["frame_index"] >= START


def test_shexp_poses_the_heldout_rows(run_dir: Path) -> None:
    from prt_torch.blockers import SphereSet, pose_spheres
    from prt_torch.compare import run_compare
    from prt_torch.compare.run import heldout_frames, load_compare_run
    from prt_torch.shexp.compare import Shexp

    rows, skin = source_poses(run_dir)
    ctx = load_compare_run(run_dir)
    fs = heldout_frames(ctx)
    np.testing.assert_array_equal(fs.rows, rows)
    assert fs.sources == [SOURCE] * len(rows)
    j = ctx.character.num_joints
    np.testing.assert_allclose(fs.skin, skin, rtol=0, atol=skin_atol(j))
    # those skins are the frames the bake traced
    pos, _ = ctx.character.skin_mesh(skin)
    np.testing.assert_allclose(fs.positions, pos, rtol=0, atol=position_atol(pos, j))
    m = Shexp()
    m.prepare(ctx, fs)
    assert "onnxruntime" in m.runtime
    spheres = SphereSet.load(RunDir(run_dir).blockers_path)
    centres = pose_spheres(spheres, skin)
    np.testing.assert_allclose(pose_spheres(m.spheres, m.skins), centres, rtol=0,
                               atol=two_path_atol(8, float(np.abs(centres).max()) + 1.0))
    v = m.visibility(fs.batch([0]))
    assert v.shape == (1, ctx.n_vertices, ctx.order**2) and np.isfinite(v).all()
    r = run_compare(run_dir, methods=["shexp"], max_frames=2, image_frames=1, reference_frames=0)
    assert [n for n in r["methods"] if "+peaks_" not in n] == ["sh_truth", "shexp"] and r["clips"] == [NAME]


def test_compare_clip_names_the_split(run_dir: Path) -> None:
    from prt_torch.compare.run import clip_frames, heldout_frames, load_compare_run

    rows, skin = source_poses(run_dir)
    ctx = load_compare_run(run_dir)
    fs, held = clip_frames(ctx, NAME), heldout_frames(ctx)
    j = ctx.character.num_joints
    np.testing.assert_array_equal(fs.frame_index, held.frame_index)
    assert fs.clips == [NAME] * len(rows) and fs.sources == [SOURCE] * len(rows)
    np.testing.assert_allclose(fs.skin, skin, rtol=0, atol=skin_atol(j))
    np.testing.assert_allclose(fs.positions, held.positions, rtol=0, atol=position_atol(held.positions, j))
    assert_bitwise(fs.features, held.features, why="the bake's posing of the same entry (resolve_clips, pose)")


def test_play_clip_names_the_split(run_dir: Path, tmp_path: Path) -> None:
    pytest.importorskip("pyvista")
    rows, _ = source_poses(run_dir)
    out = tmp_path / "tail.mp4"
    assert main(["play", str(run_dir), "--clip", NAME, "--out", str(out), "--size", "48x64"]) == 0
    t = json.loads((tmp_path / "tail.timings.json").read_text())
    assert t["clip"] == NAME and t["summary"]["frames"] == len(rows)
    from prt_torch.rig.load import clip_by_name

    rd = RunDir(run_dir)
    ch = rd.character()
    played = rd.dataset().clip_by_name(NAME, ch).clip
    assert_bitwise(played.local, ch.clips[SOURCE].local[START:],
                   why="a copy: the entry's frames are a slice of its source clip at the same rate")
    with pytest.raises(Exception, match=f"unknown clip {NAME!r}"):  # the character alone has no such clip
        clip_by_name(ch, NAME)
    # the scene player (a floor under the character) takes the split's clip too
    assert main(["play", str(run_dir), "--ground", "--clip", NAME, "--png", str(tmp_path / "png"), "--frames", "1",
                 "--size", "48x64"]) == 0
    assert len(list((tmp_path / "png").glob("*.png"))) == 1


def test_clip_by_name_rule() -> None:
    """The rule alone: a split entry that cuts or renames a clip is its source's frames; a whole-clip entry and
    any other name are the character's clip at the rate asked; an unknown name lists both sets of names."""
    from prt_torch.errors import PrtError
    from prt_torch.rig.builtin import make_character
    from prt_torch.rig.config import CharacterConfig
    from prt_torch.rig.load import clip_by_name

    ch = make_character(0.1, fps=6)
    cfg = CharacterConfig.model_validate(CONFIG["character"] | {"heldout_clips": [
        {"clip": SOURCE, "frames": f"{START}:", "name": NAME}, "wave"]})
    tail = clip_by_name(ch, NAME, cfg)
    n = ch.clips[SOURCE].num_frames
    assert tail.source == SOURCE and tail.clip.name == NAME and tail.clip.fps == 6
    np.testing.assert_array_equal(tail.frame_index, np.arange(START, n))
    head = clip_by_name(ch, f"{SOURCE}[:{START}]", cfg)
    np.testing.assert_array_equal(head.frame_index, np.arange(START))
    wave = clip_by_name(ch, "wave", cfg, fps=3)
    assert wave.source == "wave" and wave.clip.fps == 3
    np.testing.assert_array_equal(wave.frame_index, np.arange(wave.clip.num_frames))
    assert clip_by_name(ch, "run").clip is ch.clips["run"]
    with pytest.raises(PrtError, match=rf"unknown clip 'moonwalk'.*split clips: .*'{NAME}'"):
        clip_by_name(ch, "moonwalk", cfg)


def test_demo_plays_and_scores_the_split(run_dir: Path) -> None:
    """``prt demo`` on the run (bake, fit, export up to date) with a floor: the held-out video is the split's
    frames, and the scene row poses the entry's source clip at the compared row's frame."""
    pytest.importorskip("pyvista")
    rows, _ = source_poses(run_dir)
    cfg = run_dir.parent / "within_clip_scene.yaml"
    cfg.write_text(yaml.safe_dump({**CONFIG, "run_dir": str(run_dir), "scene": {"ground": {"resolution": 8}}}))
    rd = RunDir(run_dir)
    try:
        assert main(["demo", "--config", str(cfg), "--size", "48x64"]) == 0
    finally:
        rd.scene_json.unlink(missing_ok=True)  # the other tests compare the run without a scene
    m = json.loads(rd.demo_metrics.read_text())
    assert m["heldout_clip"] == NAME and m["play"]["frames"] == len(rows)
    row = m["heldout"]["comparison_row"]
    assert row in rows and m["scene"]["frame_index"] == int(rd.dataset().frame_index[row]) >= START
    assert np.isfinite(m["scene"]["vis_rel_err_in_scene"])


def test_bench_scene_takes_the_split_source(run_dir: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """``prt bench scene`` (a scene names clips of the character) plays the held-out entry's source clip."""
    capsys.readouterr()
    assert main(["bench", "scene", str(run_dir), "--frames", "1", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["clip"] == SOURCE and out["frames"] == 1

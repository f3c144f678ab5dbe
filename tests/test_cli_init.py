"""``prt init``: a humanoid glTF that is in no config - a game-style multi-mesh file written from the built-in
character (renamed joints, two skins, a rigid helmet, un-normalised weights; :mod:`tests.rig.humanoid_synth`) -
goes from ``prt init`` through ``prt bake``, ``prt train``, ``prt export`` and ``prt compare`` with no joint map
and no edit of the written config. The split, the probe-sized budget and the bad inputs are checked on their own.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
import yaml

from prt_torch.cli import main
from prt_torch.commands.init import LADDER, REFERENCE_FIT_SECONDS, Item, Probe, Split, choose_budget, plan_budget
from prt_torch.rig.builtin import make_character
from tests.rig.humanoid_synth import write_game_humanoid


def _run(capsys: pytest.CaptureFixture[str], *argv: str) -> tuple[int, str, str]:
    code = main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


@pytest.fixture()
def game(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """``game.glb`` (359 vertices + the helmet, clips walk / wave / squat at 10 fps) in the working directory."""
    monkeypatch.chdir(tmp_path)
    return write_game_humanoid(tmp_path / "game.glb", make_character(0.03, fps=10.0))


def test_init_to_compare_without_edits(game: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """The whole chain on the written config as is; the learned model beats no shadowing on the held-out clip, a
    whole clip of the file's one category that training never saw."""
    code, out, err = _run(capsys, "init", str(game), "--minutes", "0.5", "--out", "cfg/game.yaml")
    assert code == 0, err
    warnings = [line for line in err.splitlines() if line]
    assert all(line.startswith("warning: game.glb: ") for line in warnings), err
    assert any("do not sum to 1" in line for line in warnings) and any("'Crate'" in line for line in warnings)
    cfg_path = Path("cfg/game.yaml")
    text = cfg_path.read_text()
    assert "Probe: two real bakes of 16 frames: 32 rays " in text  # the measured figures are in the comments
    cfg = yaml.safe_load(text)
    ch = cfg["character"]
    assert ch["source"] == "../game.glb"  # relative to the config's directory
    names = [[e if isinstance(e, str) else e["name"] for e in ch[k]] for k in ("train_clips", "heldout_clips")]
    assert sorted(names[0]) == ["squat", "wave"] and names[1] == ["walk"]  # walk: the clip nearest 20 % of 8.2 s
    assert (cfg["bake"]["n_rays"], ch["fps"]) in LADDER
    from prt_torch.config import load_config

    run = load_config(cfg_path).out_dir  # where prt bake puts it; prt init names the same directory
    assert f"next: prt bake {cfg_path} && prt train {cfg_path} && prt export " in out
    assert Path(out.split("prt export ")[1].split(" ")[0]).resolve() == run.resolve()
    for argv in (["bake", str(cfg_path), "--no-progress"], ["train", str(cfg_path)], ["export", str(run)],
                 ["compare", str(run), "--methods", "sh_truth,unshadowed,learned_mlp", "--frames", "6",
                  "--image-frames", "1", "--reference-frames", "1", "--reference-rays", "64", "--peaks", "0"]):
        code, _, err = _run(capsys, *argv)
        assert code == 0, (argv, err)
    result = json.loads((run / "compare" / "compare.json").read_text())
    assert result["clips"] == ["walk"]
    m = result["methods"]
    assert m["sh_truth"]["vis_rel_err"] == 0.0
    assert m["learned_mlp"]["vis_rel_err"] < m["unshadowed"]["vis_rel_err"]


def test_single_clip_splits_within_the_clip(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                            capsys: pytest.CaptureFixture[str]) -> None:
    """One clip: its last quarter is held out; the two ranges, as the bake resolves them, cover every frame of the
    clip once."""
    from prt_torch.config import load_config
    from prt_torch.rig.load import check_disjoint, load_character, resolve_clips

    monkeypatch.chdir(tmp_path)
    write_game_humanoid(tmp_path / "one.glb", make_character(0.03, fps=10.0), clips=("squat",))
    code, _, err = _run(capsys, "init", "one.glb", "--minutes", "0.2")
    assert code == 0, err
    cfg = load_config(tmp_path / "one.yaml")
    (train,), (held,) = cfg.character.train_clips, cfg.character.heldout_clips
    assert train.clip == held.clip == "squat"
    character = load_character(cfg)
    capsys.readouterr()
    tr = resolve_clips(character, cfg.character.train_clips, cfg.character.fps, "train_clips")
    ho = resolve_clips(character, cfg.character.heldout_clips, cfg.character.fps, "heldout_clips")
    check_disjoint(tr, ho)
    n = character.clips["squat"].resample(cfg.character.fps).num_frames
    assert np.array_equal(np.sort(np.concatenate([tr[0].frame_index, ho[0].frame_index])), np.arange(n))
    assert 0.15 * n <= ho[0].frame_index.size <= 0.35 * n


def test_motions_hold_out_a_category(shared_data: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                     capsys: pytest.CaptureFixture[str]) -> None:
    """RiggedFigure with CMU clips of three subjects: the motions are retargeted, one whole subject is held out
    and the character's own clip trains; the config reads back as a valid run config."""
    from prt_torch.config import load_config
    from prt_torch.rig.load import load_character

    monkeypatch.chdir(tmp_path)
    motions = tmp_path / "motions"
    motions.mkdir()
    for name in ("09_01.bvh", "09_06.bvh", "02_03.bvh", "13_39.bvh"):
        shutil.copy(shared_data / "motion" / name, motions / name)
    code, out, err = _run(capsys, "init", str(shared_data / "characters" / "RiggedFigure.glb"), "--motion",
                          str(motions), "--minutes", "1", "--json")
    assert code == 0, err
    plan = json.loads(out)
    cats = {c["name"]: c["category"] for c in plan["clips"]}
    assert cats == {"animation_0": "RiggedFigure clips", "09_01": "cmu_9", "09_06": "cmu_9", "02_03": "cmu_2",
                    "13_39": "cmu_13"}
    held = set(plan["heldout_clips"])
    assert len({cats[h] for h in held}) == 1 and {n for n, c in cats.items() if c == cats[next(iter(held))]} == held
    assert "animation_0" in plan["train_clips"] and held.isdisjoint(plan["train_clips"])
    assert all(line.startswith("warning: ") for line in err.splitlines() if line)
    cfg = load_config(tmp_path / "RiggedFigure.yaml")
    character = load_character(cfg)
    assert set(character.clips) >= set(cats)


def test_quadruped_is_refused(shared_data: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                              capsys: pytest.CaptureFixture[str]) -> None:
    monkeypatch.chdir(tmp_path)
    code, out, err = _run(capsys, "init", str(shared_data / "characters" / "Fox.glb"))
    assert code == 2 and out == ""
    assert err.count("\n") == 1 and err.startswith("error: prt init needs a humanoid character: Fox.glb: ")
    assert not Path("Fox.yaml").exists()


@pytest.mark.parametrize("argv, match", [
    (["init", "missing.glb"], "character file not found"),
    (["init", "game.bvh"], "expected a .glb/.gltf character"),
    (["init", "game.glb", "--minutes", "0"], "--minutes must be in"),
    (["init", "game.glb", "--motion", "nowhere"], "--motion nowhere: no such file or directory"),
    (["init", "game.glb", "--out", "game.txt"], "expected a .yaml file"),
    (["init", "game.glb", "--out", "taken.yaml"], "taken.yaml exists (--force overwrites it)"),
])
def test_bad_input_is_one_line(game: Path, capsys: pytest.CaptureFixture[str], argv: list[str], match: str) -> None:
    Path("taken.yaml").write_text("keep me\n")
    code, out, err = _run(capsys, *argv)
    assert code == 2 and out == ""
    assert err.count("\n") == 1 and err.startswith("error: ") and match in err, err
    assert Path("taken.yaml").read_text() == "keep me\n"
    assert sorted(p.name for p in Path(".").iterdir()) == ["game.glb", "taken.yaml"]


def test_no_animation_and_no_motion_is_refused(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                               capsys: pytest.CaptureFixture[str]) -> None:
    monkeypatch.chdir(tmp_path)
    write_game_humanoid(tmp_path / "still.glb", make_character(0.03, fps=10.0), clips=())
    code, _, err = _run(capsys, "init", "still.glb")
    assert code == 2 and "still.glb has no animations; pass --motion" in err.splitlines()[-1]
    assert not Path("still.yaml").exists()


def test_budget_takes_the_best_rung_that_fits() -> None:
    """With a probe of known cost the chosen rung is the first of the ladder whose estimate fits and every better
    rung's does not (with the full grid or the small one); the frames are the clips' ``floor(seconds x fps) + 1``
    plus a quarter of the training frames as random poses; a smaller budget never buys more rays x frames; below the
    last rung the clips are cut until the estimate fits."""
    pr = Probe(bake_fixed=5.0, a=2e-3, b=4e-3, fit_seconds=REFERENCE_FIT_SECONDS, load_seconds=1.0, probe_frames=16,
               traced=[])
    items = [Item("a", 6.0, "x"), Item("b", 3.0, "x"), Item("c", 1.5, "x")]
    split = Split(["a", "b"], ["c"], "")
    cost = []
    for seconds in (3000.0, 300.0, 120.0, 60.0, 40.0, 25.0, 19.0):
        b = choose_budget(items, split, pr, 1000, seconds)
        rung = LADDER.index((b.rays, b.fps))
        if b.cap_seconds is None:
            assert b.total_s <= seconds
            for rays, fps in LADDER[:rung]:  # with either grid
                assert plan_budget(items, split, pr, 1000, rays, fps, None).total_s > seconds
                assert plan_budget(items, split, pr, 1000, rays, fps, None, full_grid=False).total_s > seconds
            if b.frames >= 400 and not b.full_grid:  # the small grid only where the full one does not fit
                assert plan_budget(items, split, pr, 1000, b.rays, b.fps, None, full_grid=True).total_s > seconds
            train = int(6.0 * b.fps) + 1 + int(3.0 * b.fps) + 1
            assert b.random_poses == round(train / 4) and b.frames == train + int(1.5 * b.fps) + 1 + b.random_poses
        else:
            assert rung == len(LADDER) - 1 and b.total_s <= seconds and b.cap_seconds < 6.0
            assert plan_budget(items, split, pr, 1000, b.rays, b.fps, b.cap_seconds * 1.01).total_s > seconds
        cost.append(b.rays * b.frames)
    assert cost == sorted(cost, reverse=True)
    assert choose_budget(items, split, pr, 1000, 19.0).cap_seconds is not None  # the last budget cuts the clips
    assert len({LADDER.index((b.rays, b.fps)) for b in (choose_budget(items, split, pr, 1000, t)
                                                       for t in (3000.0, 300.0, 120.0, 60.0, 40.0))}) == 5

"""The bake plan (prt_torch.bake.plan.make_plan): clip entries, within-clip splits, random-pose sources."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from prt_torch.bake.plan import RANDOM_CLIP, add_motions, make_plan
from prt_torch.config import config_from_dict
from prt_torch.errors import PrtError
from prt_torch.rig.builtin import make_character
from prt_torch.rig.character import Character
from prt_torch.rig.clip import Clip

FPS = 5.0


@pytest.fixture(scope="module")
def small() -> Character:
    """The built-in humanoid at density 0.05 with clips at 5 fps (walk: 11 frames, stretch: 21)."""
    return make_character(0.05, fps=FPS)


def _cfg(**character: object) -> dict:
    ch = {"source": "builtin", "density": 0.05, "fps": FPS, "train_clips": ["stretch"], "heldout_clips": ["wave"],
          "random_poses": 0, "seed": 1}
    ch.update(character)
    return {"name": "t", "character": ch}


def _rows(plan, name: str) -> np.ndarray:  # noqa: ANN001
    return np.nonzero(plan.clip_id == plan.clip_names.index(name))[0]


def test_within_clip_split_frames(small: Character) -> None:
    cfg = config_from_dict(_cfg(train_clips=["stretch", {"clip": "walk", "frames": "0:7"}],
                                heldout_clips=[{"clip": "walk", "frames": "7:", "name": "walk_end"},
                                               {"clip": "squat", "times": "1.0:2.5"}], random_poses=5))
    plan = make_plan(cfg, character=small)
    assert plan.clip_names == ["stretch", "walk[0:7]", RANDOM_CLIP, "walk_end", "squat[1s:2.5s]"]
    assert plan.splits == {"train": ["stretch", "walk[0:7]", RANDOM_CLIP], "heldout": ["walk_end", "squat[1s:2.5s]"]}
    walk = small.pose("walk")
    n_walk = walk.num_frames
    assert n_walk == 11
    tr, ho = _rows(plan, "walk[0:7]"), _rows(plan, "walk_end")
    assert len(tr) == 7 and len(ho) == n_walk - 7
    np.testing.assert_array_equal(plan.frame_index[tr], np.arange(7))  # indices within the source clip
    np.testing.assert_array_equal(plan.frame_index[ho], np.arange(7, n_walk))
    assert not set(plan.frame_index[tr]) & set(plan.frame_index[ho])  # disjoint
    np.testing.assert_allclose(plan.pose[tr], walk.features[:7], atol=1e-7)
    np.testing.assert_allclose(plan.pose[ho], walk.features[7:], atol=1e-7)
    np.testing.assert_allclose(plan.skin[ho], walk.skin[7:], atol=1e-12)
    sq = _rows(plan, "squat[1s:2.5s]")  # times: frames f with 1.0 <= f / 5 < 2.5
    np.testing.assert_array_equal(plan.frame_index[sq], np.arange(5, 13))
    np.testing.assert_allclose(plan.pose[sq], small.pose("squat").features[5:13], atol=1e-7)
    n_stretch = small.clips["stretch"].num_frames
    np.testing.assert_array_equal(plan.frame_index[_rows(plan, "stretch")], np.arange(n_stretch))
    assert plan.n_frames == 21 + 7 + 5 + 4 + 8


def test_split_clips_resample_before_slicing(small: Character) -> None:
    """Frame ranges index the clip resampled at character.fps; times map to the same frames."""
    cfg = config_from_dict(_cfg(fps=10.0, train_clips=[{"clip": "walk", "times": ":1"}],
                                heldout_clips=[{"clip": "walk", "frames": "10:"}]))
    plan = make_plan(cfg, character=small)
    walk = small.pose("walk", fps=10.0)
    assert walk.num_frames == 21
    np.testing.assert_array_equal(plan.frame_index[_rows(plan, "walk[:1s]")], np.arange(10))
    np.testing.assert_array_equal(plan.frame_index[_rows(plan, "walk[10:]")], np.arange(10, 21))
    np.testing.assert_allclose(plan.pose[_rows(plan, "walk[10:]")], walk.features[10:], atol=1e-7)


def test_plain_names_unchanged(small: Character) -> None:
    """Plain names: one whole clip each, as before (and `{clip: X}` alone is the same clip)."""
    a = make_plan(config_from_dict(_cfg(random_poses=6)), character=small)
    b = make_plan(config_from_dict(_cfg(train_clips=[{"clip": "stretch"}], random_poses=6)), character=small)
    assert a.clip_names == b.clip_names == ["stretch", RANDOM_CLIP, "wave"]
    assert a.fingerprint() == b.fingerprint()


@pytest.mark.parametrize("mode", ["uniform", "sparse"])
def test_random_sources_are_the_training_range_only(small: Character, mode: str) -> None:
    """A sparse base / uniform source frame of a split clip never comes from its held-out range: the held-out range
    of walk gets a translation signature on one joint that a derived pose would keep."""
    local = small.clips["walk"].local.copy()
    local[4:, 3, :3, 3] += 5.0  # frames 4: are held out
    c = replace(small, clips={**small.clips, "walk": Clip("walk", FPS, local)}, joint_limits=None)
    cfg = config_from_dict(_cfg(train_clips=[{"clip": "walk", "frames": ":4"}], heldout_clips=[{"clip": "walk",
                                "frames": "4:"}], random_poses=120, random_mode=mode, random_base_prob=1.0))
    plan = make_plan(cfg, character=c)
    rnd = plan.skin[_rows(plan, RANDOM_CLIP)]
    ho = plan.skin[_rows(plan, "walk[4:]")]
    # the local translation of joint 3 (its bone) from the skin matrices: world = skin @ bind_world
    bind_world = [np.linalg.inv(c.inverse_bind[j]) for j in (c.parents[3], 3)]

    def bone(skin: np.ndarray) -> np.ndarray:
        world = [skin[:, j] @ w for j, w in zip((c.parents[3], 3), bind_world, strict=True)]
        return np.linalg.norm(world[1][:, :3, 3] - world[0][:, :3, 3], axis=-1)

    clean = np.linalg.norm(c.bind_local[3, :3, 3])
    assert np.all(np.abs(bone(ho) - clean) > 1.0)  # the held-out range carries it
    np.testing.assert_allclose(bone(rnd), clean, atol=1e-6)  # no random pose does


@pytest.mark.parametrize("character,msg", [
    (dict(train_clips=[{"clip": "walk", "frames": "0-7"}]), "train_clips.0.range.frames'.*bad frame range"),
    (dict(train_clips=[{"clip": "walk", "frames": "0:7:2"}]), "bad frame range"),
    (dict(train_clips=[{"clip": "walk", "frames": "7:7"}]), "empty frame range"),
    (dict(train_clips=[{"clip": "walk", "times": "2:1"}]), "empty time range"),
    (dict(train_clips=[{"clip": "walk", "times": "a:1"}]), "train_clips.0.range.times'.*bad time range"),
    (dict(train_clips=[{"clip": "walk", "times": "-1:"}]), "bad time range"),
    (dict(train_clips=[{"clip": "walk", "times": "0.01:0.1"}]), "selects no frame at 5 fps"),
    (dict(train_clips=[{"clip": "walk", "frames": "0:2", "times": "0:1"}]), "either 'frames' or 'times'"),
    (dict(train_clips=[{"clip": "walk", "frame": "0:2"}]), "unknown config key 'character.train_clips.0.range.frame'"),
    (dict(train_clips=[{"frames": "0:2"}]), "missing config key 'character.train_clips.0.range.clip'"),
    (dict(train_clips=[{"clip": "walk", "frames": "0:7"}], heldout_clips=[{"clip": "walk", "frames": "6:"}]),
     "'character.heldout_clips'.*'walk\\[6:\\]' overlaps 'walk\\[0:7\\]' in train_clips"),
    (dict(train_clips=[{"clip": "walk", "times": "0:1"}], heldout_clips=[{"clip": "walk", "frames": "4:"}]),
     "overlaps"),
    (dict(train_clips=["walk"], heldout_clips=[{"clip": "walk", "frames": "4:"}]), "overlaps"),
    (dict(train_clips=[{"clip": "walk", "frames": ":4"}, {"clip": "walk", "frames": "2:6"}]), "overlaps"),
    (dict(train_clips=[{"clip": "walk", "frames": ":4", "name": "wave"}]), "clip name 'wave' is already used"),
])
def test_bad_clip_entries_are_config_errors(character: dict, msg: str) -> None:
    with pytest.raises(PrtError, match=msg):
        config_from_dict(_cfg(**character))


def test_bad_clip_entries_against_the_character(small: Character) -> None:
    def plan(**ch: object) -> None:
        make_plan(config_from_dict(_cfg(**ch)), character=small)

    with pytest.raises(PrtError, match=r"unknown clip 'moonwalk' in train_clips\[0\]"):
        plan(train_clips=[{"clip": "moonwalk", "frames": ":3"}])
    with pytest.raises(PrtError, match=r"heldout_clips\[0\]: 'walk\[20:\]' selects no frame of clip 'walk' \(11 "):
        plan(train_clips=["stretch"], heldout_clips=[{"clip": "walk", "frames": "20:"}])
    with pytest.raises(PrtError, match="share frames of clip 'walk'"):  # negative indices: only the plan can tell
        plan(train_clips=[{"clip": "walk", "frames": ":8"}], heldout_clips=[{"clip": "walk", "frames": "-4:"}])
    with pytest.raises(PrtError, match="clashes with the random poses"):
        plan(train_clips=[{"clip": "walk", "name": RANDOM_CLIP}], random_poses=2)
    plan(train_clips=[{"clip": "walk", "frames": ":7"}], heldout_clips=[{"clip": "walk", "frames": "-4:"}])  # fine


# -- character.motions: motion files retargeted onto the character (prt_torch.rig.retarget) ---------------
def test_motions_become_clips_and_change_the_fingerprint(small: Character, shared_data, tmp_path) -> None:  # noqa: ANN001
    import shutil

    from prt_torch.rig.retarget import retarget_file

    bvh = tmp_path / "walk.bvh"
    shutil.copy(shared_data / "motion" / "131_01.bvh", bvh)
    raw = _cfg(motions=[{"file": "walk.bvh", "name": "mocap", "frames": "2:30"}],
               train_clips=["stretch", {"clip": "mocap", "frames": "0:20"}],
               heldout_clips=[{"clip": "mocap", "frames": "20:", "name": "mocap_end"}])
    cfg = config_from_dict(raw, base_dir=tmp_path)  # `file` resolved against the config's directory
    plan = make_plan(cfg, character=replace(small, clips=dict(small.clips)))
    assert plan.clip_names == ["stretch", "mocap[0:20]", "mocap_end"]
    want, _ = retarget_file(bvh, small, fps=FPS)
    tr = _rows(plan, "mocap[0:20]")
    np.testing.assert_array_equal(plan.frame_index[tr], np.arange(20))
    np.testing.assert_allclose(plan.skin[tr], (small.pose(Clip("m", FPS, want.local[2:22]))).skin, atol=1e-9)
    assert len(_rows(plan, "mocap_end")) == 8
    text = bvh.read_text().splitlines()
    first = next(i for i, line in enumerate(text) if line.startswith("Frame Time")) + 1
    for i in range(first + 200, first + 260):  # motion values change (source frames 200-259: in the slice)
        text[i] = " ".join(f"{float(v) + 3.0:.4f}" for v in text[i].split())
    bvh.write_text("\n".join(text) + "\n")
    plan2 = make_plan(config_from_dict(raw, base_dir=tmp_path), character=replace(small, clips=dict(small.clips)))
    assert plan2.fingerprint() != plan.fingerprint()


def test_bad_motions_are_one_line_errors(small: Character, shared_data, tmp_path) -> None:  # noqa: ANN001
    cases = [({"file": "missing.bvh", "name": "m"}, "motion file not found"),
             ({"file": str(shared_data / "characters" / "Fox.glb"), "name": "m"}, "humanoid"),
             ({"file": str(shared_data / "motion" / "131_01.bvh"), "name": "walk"}, "already has a clip"),
             ({"file": str(shared_data / "motion" / "131_01.bvh"), "name": "m", "joint_map": {"Nope": "head"}},
              "Nope"),
             ({"file": str(shared_data / "motion" / "131_01.bvh"), "name": "m", "frames": "5000:"}, "no frame")]
    for motion, msg in cases:
        cfg = config_from_dict(_cfg(motions=[motion]), base_dir=tmp_path)
        with pytest.raises(PrtError, match=msg) as e:
            add_motions(cfg, replace(small, clips=dict(small.clips)))
        assert "\n" not in str(e.value) and "character.motions[0]" in str(e.value)
    with pytest.raises(PrtError, match="used twice"):
        config_from_dict(_cfg(motions=[{"file": "a.bvh", "name": "m"}, {"file": "b.bvh", "name": "m"}]))
    with pytest.raises(PrtError, match="motions"):
        config_from_dict(_cfg(motions=[{"file": "a.bvh", "name": "m", "speed": 2}]))


def test_keys_without_effect_on_the_character_warn(tmp_path) -> None:  # noqa: ANN001
    """``character.density`` (built-in humanoid only) on a glTF character, ``height`` (glTF only) and
    ``random_perturb_deg`` (characters without joint limits only) on the built-in one: one warning each, naming the
    key, and the character is the one loaded without the key. Keys left at their defaults, or that apply, are
    silent."""
    import warnings

    from prt_torch.bake.plan import load_character
    from prt_torch.errors import PrtWarning
    from prt_torch.rig.gltf import load_gltf
    from tests.rig.test_gltf import write_rig

    rig = write_rig(tmp_path / "rig.glb")

    def load(**character: object) -> tuple[Character, list[str]]:
        cfg = config_from_dict({"name": "t", "character": {"fps": FPS, **character}}, base_dir=tmp_path)
        with warnings.catch_warnings(record=True) as record:
            warnings.simplefilter("always")
            ch = load_character(cfg)
        return ch, [str(w.message) for w in record if issubclass(w.category, PrtWarning)]

    ch, got = load(source="rig.glb", density=0.5, height=1.8, random_perturb_deg=10.0)
    assert got == ["character.density has no effect on a glTF character (it sets the built-in humanoid's vertex "
                   "density); ignored"]
    assert ch.content_hash() == load_gltf(rig, fps=FPS, height=1.8).content_hash()
    ch, got = load(source="builtin", density=0.05, height=1.8, random_perturb_deg=10.0)
    assert got == ["character.height has no effect on the built-in character (it rescales a glTF file); ignored",
                   "character.random_perturb_deg has no effect on a character with joint limits (the built-in "
                   "humanoid's random poses are drawn within its limits); ignored"]
    assert ch.content_hash() == make_character(0.05, fps=FPS).content_hash()
    assert load(source="rig.glb", height=1.8, random_perturb_deg=10.0)[1] == []
    assert load(source="builtin", density=0.05)[1] == []

"""Character: posing, persistence, hashing, validation, no torch on import."""

from __future__ import annotations

import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from prt_torch.errors import PrtError
from prt_torch.rig.character import Character
from tests.tolerance import assert_bitwise


def test_bind_pose_reproduces_rest_mesh(humanoid: Character) -> None:
    poses = humanoid.pose(humanoid.bind_clip())
    np.testing.assert_allclose(poses.skin[0], np.tile(np.eye(4), (humanoid.num_joints, 1, 1)), atol=1e-12)
    pos, nrm = humanoid.skin_mesh(poses)
    np.testing.assert_allclose(pos[0], humanoid.rest_vertices, atol=1e-5)
    np.testing.assert_allclose(nrm[0], humanoid.rest_normals, atol=1e-5)
    np.testing.assert_allclose(poses.features, np.tile([1, 0, 0, 0, 1, 0], (1, humanoid.num_joints - 1)), atol=1e-6)


def test_pose_shapes_and_resampling(humanoid: Character) -> None:
    p = humanoid.pose("walk")
    f, j = p.num_frames, humanoid.num_joints
    assert p.local.shape == p.world.shape == p.skin.shape == (f, j, 4, 4)
    assert p.features.shape == (f, humanoid.feature_width) and p.features.dtype == np.float32
    q = humanoid.pose("walk", fps=60)
    assert q.num_frames == 2 * f - 1 and q.fps == 60
    np.testing.assert_allclose(q.features[::2], p.features, atol=1e-5)
    pos, nrm = humanoid.skin_mesh(q.skin[:3])
    assert pos.shape == nrm.shape == (3, humanoid.num_vertices, 3) and pos.dtype == np.float32


def test_save_load_round_trip(humanoid: Character, tmp_path: Path) -> None:
    path = tmp_path / "sub" / "character.npz"
    humanoid.save(path)
    assert [p.name for p in path.parent.iterdir()] == ["character.npz"]  # no temporary left behind
    c = Character.load(path)
    assert c.content_hash() == humanoid.content_hash()
    assert c.joint_names == humanoid.joint_names and c.name == humanoid.name
    assert list(c.clips) == list(humanoid.clips)
    for name, clip in humanoid.clips.items():
        assert_bitwise(c.clips[name].local, clip.local, why='npz round trip')
        assert c.clips[name].fps == clip.fps
    assert_bitwise(c.joint_limits, humanoid.joint_limits, why='npz round trip')
    assert_bitwise(c.pose("squat").features, humanoid.pose("squat").features,
                   why='the same operations on round-tripped inputs')


def test_content_hash_tracks_geometry(humanoid: Character) -> None:
    moved = humanoid.rest_vertices.copy()
    moved[0, 0] += 1e-3
    other = replace(humanoid, rest_vertices=moved)
    assert other.content_hash() != humanoid.content_hash()
    assert replace(humanoid, clips={}).content_hash() == humanoid.content_hash()


def test_bad_inputs(humanoid: Character, tmp_path: Path) -> None:
    nan = humanoid.rest_vertices.copy()
    nan[3, 1] = np.nan
    with pytest.raises(PrtError, match="NaN"):
        replace(humanoid, rest_vertices=nan)
    w = humanoid.weights.copy()
    w[5] *= 0.8
    with pytest.raises(PrtError, match="sum to 1"):
        replace(humanoid, weights=w)
    with pytest.raises(PrtError, match="face indices"):
        replace(humanoid, faces=humanoid.faces + humanoid.num_vertices)
    with pytest.raises(PrtError, match=r"unknown clip 'moonwalk'"):
        humanoid.pose("moonwalk")
    with pytest.raises(PrtError, match="skin matrices"):
        humanoid.skin_mesh(np.zeros((2, 3, 4, 4)))
    with pytest.raises(PrtError, match="not found"):
        Character.load(tmp_path / "missing.npz")
    (tmp_path / "junk.npz").write_bytes(b"junk")
    with pytest.raises(PrtError, match="not a character"):
        Character.load(tmp_path / "junk.npz")
    for e in (PrtError,):
        assert issubclass(e, ValueError)


def test_rig_imports_without_torch() -> None:
    code = ("import sys, prt_torch.rig, prt_torch.rig.builtin, prt_torch.rig.gltf, prt_torch.rig.bvh;"
            "c = prt_torch.rig.builtin.make_character(0.05); c.skin_mesh(c.pose('walk'));"
            "assert 'torch' not in sys.modules, 'torch imported'")
    subprocess.run([sys.executable, "-c", code], check=True)


def test_scaled_commutes_with_skinning(humanoid: Character) -> None:
    big = humanoid.scaled(2.5)
    for name in ("walk", "stretch"):
        a, na = humanoid.skin_mesh(humanoid.pose(name))
        b, nb = big.skin_mesh(big.pose(name))
        np.testing.assert_allclose(b, 2.5 * a, atol=1e-4)
        np.testing.assert_allclose(nb, na, atol=1e-5)
        np.testing.assert_allclose(big.pose(name).features, humanoid.pose(name).features, atol=1e-6)
    with pytest.raises(PrtError, match="scale factor"):
        humanoid.scaled(-1.0)

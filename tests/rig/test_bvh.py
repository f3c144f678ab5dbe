"""BVH loading: a synthetic file against hand-built FK, and the CMU sample."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from prt_torch.errors import PrtError
from prt_torch.rig.bvh import load_bvh
from prt_torch.rig.skeleton import forward_kinematics

SYNTH = """HIERARCHY
ROOT Hips
{
  OFFSET 0 0 0
  CHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation
  JOINT Spine
  {
    OFFSET 0 2 0.5
    CHANNELS 3 Yrotation Xrotation Zrotation
    JOINT Head
    {
      OFFSET 0.3 1.5 0
      CHANNELS 3 Xrotation Zrotation Yrotation
      End Site
      {
        OFFSET 0 1 0
      }
    }
  }
  JOINT Leg
  {
    OFFSET 1 -1 0
    CHANNELS 3 Zrotation Yrotation Xrotation
    End Site
    {
      OFFSET 0 -2 0
    }
  }
}
MOTION
Frames: 3
Frame Time: 0.04
"""


def elementary(axis: str, deg: float) -> np.ndarray:
    c, s = np.cos(np.radians(deg)), np.sin(np.radians(deg))
    return {"X": np.array([[1, 0, 0], [0, c, -s], [0, s, c]]),
            "Y": np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]]),
            "Z": np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])}[axis]


def test_synthetic_bvh_fk(tmp_path: Path) -> None:
    rng = np.random.default_rng(0)
    data = rng.uniform(-170, 170, size=(3, 15))
    data[:, :3] = rng.normal(size=(3, 3))
    data = np.round(data, 6)  # what the file holds
    p = tmp_path / "s.bvh"
    p.write_text(SYNTH + "\n".join(" ".join(f"{x:.6f}" for x in row) for row in data) + "\n")
    scale = 0.5
    skel, clip = load_bvh(p, scale=scale)
    assert skel.joint_names == ["Hips", "Spine", "Head", "Leg"]
    assert list(skel.parents) == [-1, 0, 1, 0]
    assert clip.num_frames == 3 and clip.fps == pytest.approx(25.0)
    assert [e[0] for e in skel.end_sites] == [2, 3]
    world = forward_kinematics(skel.parents, clip.local)
    offsets = {"Spine": [0, 2, 0.5], "Head": [0.3, 1.5, 0], "Leg": [1, -1, 0]}
    orders = {"Hips": "ZXY", "Spine": "YXZ", "Head": "XZY", "Leg": "ZYX"}
    cols = {"Hips": 3, "Spine": 6, "Head": 9, "Leg": 12}
    to_z = np.array([[1, 0, 0], [0, 0, -1], [0, 1, 0]])
    for f in range(3):
        rots = {}
        for name, order in orders.items():
            r = np.eye(3)
            for k, ax in enumerate(order):
                r = r @ elementary(ax, data[f, cols[name] + k])
            rots[name] = r
        # hand-built FK in the BVH (y-up) frame, converted to z-up at the end
        hips_r, hips_t = rots["Hips"], data[f, :3] * scale
        spine_r = hips_r @ rots["Spine"]
        spine_t = hips_t + hips_r @ (np.array(offsets["Spine"]) * scale)
        head_r = spine_r @ rots["Head"]
        head_t = spine_t + spine_r @ (np.array(offsets["Head"]) * scale)
        leg_r = hips_r @ rots["Leg"]
        leg_t = hips_t + hips_r @ (np.array(offsets["Leg"]) * scale)
        for j, (r, t) in enumerate([(hips_r, hips_t), (spine_r, spine_t), (head_r, head_t), (leg_r, leg_t)]):
            np.testing.assert_allclose(world[f, j, :3, :3], to_z @ r, atol=1e-9)
            np.testing.assert_allclose(world[f, j, :3, 3], to_z @ t, atol=1e-9)


@pytest.mark.parametrize("text, match", [
    ("HIERARCHY\nROOT A\n{\nOFFSET 0 0 0\nCHANNELS 1 Xrotation\n}\n", "not a BVH file"),
    (SYNTH.replace("Frames: 3", "Frames: 4") + "0 " * 45, "expected 4 frames"),
    (SYNTH.replace("Zrotation Yrotation Xrotation", "Zrotation Yrotation Wrotation") + "0 " * 45,
     "unknown BVH channel"),
    (SYNTH + "0 " * 44 + "nan", "malformed|NaN"),
])
def test_bad_bvh(tmp_path: Path, text: str, match: str) -> None:
    p = tmp_path / "bad.bvh"
    p.write_text(text)
    with pytest.raises(PrtError, match=match):
        load_bvh(p)


def test_missing_bvh(tmp_path: Path) -> None:
    with pytest.raises(PrtError, match="not found"):
        load_bvh(tmp_path / "nope.bvh")


def test_cmu_131_01(shared_data: Path) -> None:
    skel, clip = load_bvh(shared_data / "motion" / "131_01.bvh", scale=0.056444)
    assert len(skel.joint_names) == 31
    assert clip.num_frames == 994
    assert clip.fps == pytest.approx(120.0, rel=1e-3)
    world = forward_kinematics(skel.parents, clip.local)
    names = skel.joint_names
    head, toe, hips = names.index("Head"), names.index("LeftToe"), names.index("Hips")
    z = world[..., 2, 3]
    assert np.all(z[:, head] > z[:, hips]) and np.all(z[:, hips] > z[:, toe])  # z up
    height = z[:, head] - z[:, [toe, names.index("RightToe")]].min(1)
    assert 1.0 < np.median(height) < 2.0  # metres with the CMU scale
    bind = skel.bind_world()
    assert bind.shape == (31, 4, 4) and np.allclose(bind[0, :3, :3], [[1, 0, 0], [0, 0, -1], [0, 1, 0]])

"""Scene placement, timing, the automatic ground, the overlap check (numpy references: rigid transforms)."""

from __future__ import annotations

import numpy as np
import pytest

from prt_torch.errors import PrtError
from prt_torch.rig.builtin import make_character
from prt_torch.scene.config import GroundConfig
from prt_torch.scene.scene import Actor, check_separated, placement_matrix, pose_actor, scene_ground


@pytest.fixture(scope="module")
def character():
    return make_character(density=0.05, fps=10)


def test_placement_is_a_rigid_transform_of_the_posed_mesh(character) -> None:
    clip = character.clip("walk")
    a0 = Actor(character, clip)
    a1 = Actor(character, clip, placement_matrix([1.5, -2.0, 0.25], 30.0))
    p0 = pose_actor(a0, a0.locals(np.arange(3), clip.fps)).positions.astype(np.float64)
    p1 = pose_actor(a1, a1.locals(np.arange(3), clip.fps)).positions.astype(np.float64)
    c, s = np.cos(np.radians(30.0)), np.sin(np.radians(30.0))
    rz = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
    np.testing.assert_allclose(p1, p0 @ rz.T + [1.5, -2.0, 0.25], atol=1e-5)
    # pose features exclude the root: the learned visibility does not see the placement
    from prt_torch.rig.features import pose_features

    l0, l1 = a0.locals(np.arange(3), clip.fps), a1.locals(np.arange(3), clip.fps)
    np.testing.assert_allclose(pose_features(l0, character.bind_local, character.parents),
                               pose_features(l1, character.bind_local, character.parents), atol=1e-6)


def test_time_offset_loops_the_clip(character) -> None:
    clip = character.clip("wave")
    n = clip.local.shape[0]
    a = Actor(character, clip, time_offset=2.0 / clip.fps)
    np.testing.assert_array_equal(a.frame_indices(np.array([0, n - 2, n - 1]), clip.fps), [2, 0, 1])
    # a scene at another rate picks the nearest clip frame
    np.testing.assert_array_equal(Actor(character, clip).frame_indices(np.array([0, 1, 2]), 2 * clip.fps), [0, 0, 1])


def test_ground_auto(character) -> None:
    clip = character.clip("squat")
    actors = [Actor(character, clip), Actor(character, clip, placement_matrix([2.0, 0.0, 0.5]))]
    g = scene_ground(GroundConfig(resolution=4), actors)
    rest = character.rest_vertices
    height = float(rest[:, 2].max() - rest[:, 2].min())
    assert g.height == pytest.approx(float(rest[:, 2].min()))  # the lowest placed rest point
    assert g.size == pytest.approx(float(rest[:, 0].max() - rest[:, 0].min()) + 2.0 + 3.0 * height, rel=1e-5)
    assert g.vertices.shape == (25, 3) and g.faces.shape == (32, 3)
    # the ground's triangles face up (+z) and tile the square
    v = g.vertices[g.faces].astype(np.float64)
    nrm = np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])
    assert np.all(nrm[:, 2] > 0) and nrm[:, 2].sum() / 2 == pytest.approx(g.size ** 2, rel=1e-5)
    # z: clip = the lowest posed vertex over the frames played (the squat lowers no foot below the rest soles)
    gc = scene_ground(GroundConfig(resolution=4, z="clip"), actors[:1], clip.fps, clip.local.shape[0])
    posed = pose_actor(actors[0], actors[0].locals(np.arange(clip.local.shape[0]), clip.fps)).positions
    assert gc.height == pytest.approx(float(posed[..., 2].min()), abs=1e-6)
    assert scene_ground(GroundConfig(resolution=4, z=-0.2, size=3.0), actors).height == -0.2


def test_overlap_check() -> None:
    c = [np.array([[0.0, 0.0, 1.0]]), np.array([[0.5, 0.0, 1.0]])]
    check_separated(c, [np.array([0.2]), np.array([0.2])], ["a", "b"])  # 0.1 apart: fine
    with pytest.raises(PrtError, match="a and b overlap at frame 3") as e:
        check_separated(c, [np.array([0.3]), np.array([0.3])], ["a", "b"], frame=3)
    assert "\n" not in str(e.value)

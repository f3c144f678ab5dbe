"""Forward kinematics and clip resampling."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation, Slerp

from prt_torch.errors import PrtError
from prt_torch.rig.clip import Clip
from prt_torch.rig.skeleton import check_parents, forward_kinematics, world_to_local


def random_local(f: int, j: int, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    m = np.tile(np.eye(4), (f, j, 1, 1))
    m[..., :3, :3] = Rotation.random(f * j, random_state=seed).as_matrix().reshape(f, j, 3, 3)
    m[..., :3, 3] = rng.normal(size=(f, j, 3))
    return m


def test_fk_matches_chain_products() -> None:
    parents = np.array([-1, 0, 1, 0, 3, 4])
    local = random_local(4, 6)
    world = forward_kinematics(parents, local)
    for j in range(6):
        chain, k = [], j
        while k >= 0:
            chain.append(k)
            k = parents[k]
        ref = np.tile(np.eye(4), (4, 1, 1))
        for k in reversed(chain):
            ref = ref @ local[:, k]
        np.testing.assert_allclose(world[:, j], ref, atol=1e-12)
    np.testing.assert_allclose(world_to_local(parents, world), local, atol=1e-10)


def test_bad_parents() -> None:
    with pytest.raises(PrtError, match="topological"):
        check_parents(np.array([-1, 2, 0]))
    with pytest.raises(PrtError, match="local transforms"):
        forward_kinematics(np.array([-1, 0]), np.zeros((3, 3, 4, 4)))


def test_resample_slerp() -> None:
    local = random_local(5, 3, seed=1)
    clip = Clip("c", 10.0, local)
    same = clip.resample(10.0)
    np.testing.assert_allclose(same.local, local)
    up = clip.resample(20.0)
    assert up.num_frames == 9 and up.fps == 20.0
    np.testing.assert_allclose(up.local[::2], local, atol=1e-10)
    for j in range(3):
        rots = Rotation.from_matrix(local[:, j, :3, :3])
        ref = Slerp(np.arange(5) / 10.0, rots)(np.arange(9) / 20.0).as_matrix()
        np.testing.assert_allclose(up.local[:, j, :3, :3], ref, atol=1e-10)
    np.testing.assert_allclose(up.local[1, :, :3, 3], 0.5 * (local[0, :, :3, 3] + local[1, :, :3, 3]), atol=1e-12)
    down = clip.resample(4.0)
    assert down.num_frames == 2  # duration 0.4 s -> frames at 0 and 0.25 s


def test_clip_validation() -> None:
    with pytest.raises(PrtError, match="NaN"):
        Clip("x", 30.0, np.full((2, 3, 4, 4), np.nan))
    with pytest.raises(PrtError, match="fps"):
        Clip("x", 0.0, np.tile(np.eye(4), (2, 3, 1, 1)))
    with pytest.raises(PrtError, match=r"\(F, J, 4, 4\)"):
        Clip("x", 30.0, np.zeros((3, 4, 4)))

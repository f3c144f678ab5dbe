"""6D pose features."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from prt_torch.errors import PrtError
from prt_torch.rig.features import features_to_rotations, pose_features


def test_bind_pose_maps_to_constant_and_root_excluded() -> None:
    bind = Rotation.random(5, random_state=0).as_matrix()
    local = np.tile(bind, (3, 1, 1, 1))
    local[:, 0] = Rotation.random(3, random_state=1).as_matrix()  # root orientation varies
    f = pose_features(local, bind, np.array([-1, 0, 1, 1, 0]))
    assert f.shape == (3, 24) and f.dtype == np.float32
    np.testing.assert_allclose(f, np.tile([1, 0, 0, 0, 1, 0], (3, 4)), atol=1e-6)


def test_features_invert_to_bind_relative_rotation() -> None:
    bind = Rotation.random(4, random_state=2).as_matrix()
    local = Rotation.random(12, random_state=3).as_matrix().reshape(3, 4, 3, 3)
    f = pose_features(local, bind, exclude_root=False)
    rel = features_to_rotations(f)
    np.testing.assert_allclose(rel, np.swapaxes(bind, -1, -2)[None] @ local, atol=1e-6)


def test_continuous_through_180_degrees() -> None:
    # a rotation sweeping through +-180 degrees: Euler angles jump by 360, the 6D features do not
    ang = np.radians(np.linspace(170, 190, 41))
    local = Rotation.from_rotvec(np.outer(ang, [0, 0, 1])).as_matrix()[:, None]
    f = pose_features(np.concatenate([np.tile(np.eye(3), (41, 1, 1, 1)), local], 1), np.tile(np.eye(3), (2, 1, 1)),
                      np.array([-1, 0]))
    euler = Rotation.from_matrix(local[:, 0]).as_euler("xyz")[:, 2]
    assert np.abs(np.diff(euler)).max() > 6  # wrap-around
    assert np.abs(np.diff(f, axis=0)).max() < 0.01


def test_bad_features_input() -> None:
    with pytest.raises(PrtError, match="NaN"):
        pose_features(np.full((1, 2, 3, 3), np.nan), np.tile(np.eye(3), (2, 1, 1)))
    with pytest.raises(PrtError, match="bind rotations"):
        pose_features(np.tile(np.eye(3), (1, 2, 1, 1)), np.tile(np.eye(3), (3, 1, 1)))

"""Pose-space interpolation (seed 001 eq. 6-7): NRBF weights, the bone-weighted k-d tree, segment rotations."""

from __future__ import annotations

import numpy as np
import pytest

from prt_torch.errors import PrtError
from prt_torch.s001.posespace import (
    PoseSpace,
    interpolate_coefficients,
    nrbf_weights,
    segment_bone_weights,
    segment_rotations,
)
from tests.tolerance import assert_bitwise


def _space(p: int = 24, joints: int = 3, k: int = 2, seed: int = 0) -> PoseSpace:
    rng = np.random.default_rng(seed)
    poses = rng.normal(size=(p, 6 * joints))
    jw = rng.uniform(0.2, 1.0, size=(k, joints))
    groups = np.stack([rng.permutation(np.arange(p) // 4) for _ in range(k)])
    return PoseSpace(poses, jw, groups)


def test_nrbf_reproduces_sampled_poses_exactly() -> None:
    sp = _space()
    coeffs = np.random.default_rng(1).normal(size=(sp.poses.shape[0], 5, 3))  # (P, V, nb)
    seg = np.array([0, 1, 0, 1, 1])
    for j in range(sp.poses.shape[0]):
        idx, alpha = sp.segment_neighbours(sp.poses[j])
        assert np.all(alpha[idx == j] == 1.0) and np.all(alpha[idx != j] == 0.0)
        lam = interpolate_coefficients(coeffs, idx[seg], alpha[seg])
        assert_bitwise(lam, coeffs[j],
                       why="weights exactly one-hot (1.0 and 0.0): the sampled pose's coefficients, copied")
        gi, ga = sp.global_neighbours(sp.poses[j])
        assert gi[np.argmax(ga)] == j and ga.max() == 1.0


def test_weights_are_convex_and_the_nearest_pose_is_the_bone_weighted_one() -> None:
    sp = _space()
    rng = np.random.default_rng(2)
    for _ in range(20):
        q = rng.normal(size=sp.poses.shape[1])
        idx, alpha = sp.segment_neighbours(q)
        assert np.all(alpha >= 0) and np.allclose(alpha.sum(axis=1), 1.0)
        for k in range(sp.n_segments):
            # brute-force eq. 6: sum_j w_kj ||f_j(p) - f_j(q)||^2, its argmin's group holds the neighbours
            d2 = (((sp.poses - q).reshape(len(sp.poses), -1, 6) ** 2).sum(-1) * sp.joint_weights[k]).sum(-1)
            nearest = int(np.argmin(d2))
            assert nearest in idx[k][alpha[k] > 0] or alpha[k][idx[k] == nearest].size
            assert set(idx[k]) <= set(np.flatnonzero(sp.groups[k] == sp.groups[k, nearest]))
        gi, ga = sp.global_neighbours(q)
        assert np.all(ga >= 0) and ga.sum() == pytest.approx(1.0)
        brute = np.argsort(((sp.poses - q) ** 2).sum(-1))[: len(gi)]
        assert set(gi) == set(brute)


def test_linear_field_symmetric_configuration_is_exact_and_nrbf_beats_nearest() -> None:
    # samples on a line at t = 0..5 (one joint's first feature), one group; a linear field is reproduced exactly at the
    # centre 2.5 (symmetric weights) and, everywhere, better than by the nearest sample
    t = np.arange(6.0)
    poses = np.zeros((6, 6))
    poses[:, 0] = t
    sp = PoseSpace(poses, np.ones((1, 1)), np.zeros((1, 6), np.int64))
    a, b = 2.5, -1.0
    field = a * t + b
    errs_nrbf, errs_near = [], []
    for q in [*np.linspace(0.1, 4.9, 24), 2.5]:
        pose = np.zeros(6)
        pose[0] = q
        idx, alpha = sp.segment_neighbours(pose)
        est = float(alpha[0] @ field[idx[0]])
        truth = a * q + b
        if abs(q - 2.5) < 1e-9:  # the centre: symmetric neighbours
            assert est == pytest.approx(truth, abs=1e-9)
        errs_nrbf.append(abs(est - truth))
        errs_near.append(abs(field[int(np.clip(np.round(q), 0, 5))] - truth))
    assert np.mean(errs_nrbf) < 0.5 * np.mean(errs_near)


def test_segment_bone_weights_by_hand() -> None:
    seg = np.array([0, 0, 1])
    joints = np.array([[1, 2], [1, 3], [3, 2]])
    weights = np.array([[0.75, 0.25], [1.0, 0.0], [0.5, 0.5]])
    w = segment_bone_weights(seg, joints, weights, 2, np.array([1, 2, 3]), other=0.1)
    # segment 0: joint1 1.75, joint2 0.25, joint3 0 -> /1.75 ; segment 1: joint2 .5, joint3 .5
    np.testing.assert_allclose(w, [[1.0, 0.25 / 1.75, 0.1], [0.1, 1.0, 1.0]])


def test_segment_rotations_recover_a_rigid_rotation() -> None:
    from scipy.spatial.transform import Rotation

    rng = np.random.default_rng(3)
    ref = Rotation.random(10, random_state=4).as_matrix()
    seg = np.array([0] * 5 + [1] * 5)
    r = Rotation.random(2, random_state=5).as_matrix()
    posed = ref @ np.swapaxes(r[seg], -1, -2)  # F = F_ref R^T
    got = segment_rotations(posed + 1e-9 * rng.normal(size=posed.shape), ref, seg, 2)
    np.testing.assert_allclose(got, r, atol=1e-6)


def test_bad_input_is_one_line() -> None:
    sp = _space()
    with pytest.raises(PrtError, match="features") as e:
        sp.segment_neighbours(np.zeros(5))
    assert "\n" not in str(e.value)
    with pytest.raises(PrtError, match="finite"):
        nrbf_weights(np.array([[1.0, -1.0]]))
    with pytest.raises(PrtError, match="NaN"):
        sp.global_neighbours(np.full(sp.poses.shape[1], np.nan))
    with pytest.raises(PrtError, match="groups"):
        PoseSpace(sp.poses, sp.joint_weights, sp.groups[:, :3])

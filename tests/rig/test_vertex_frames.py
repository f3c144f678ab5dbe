"""Local vertex frames: mean-shift clusters, PCA axes, orthonormality, rigid equivariance, coherence."""

from __future__ import annotations

import math
import sys

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from prt_torch.errors import PrtError
from prt_torch.rig.vertex_frames import (
    FALLBACK_BELOW,
    cluster_axes,
    cluster_bones,
    cluster_vertices,
    vertex_frames,
)
from tests.tolerance import two_path_atol


def two_bone_arm() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """An open tube of radius 0.4 along x from 0 to 4 (41 rings of 24 vertices), bone 0 on x < 2 and
    bone 1 on x > 2, with a linear weight blend over 1.5..2.5.

    Returns ``(vertices (V, 3), normals (V, 3), dense weights (V, 2))``.
    """
    x, a = np.meshgrid(np.linspace(0.0, 4.0, 41), np.linspace(0, 2 * math.pi, 24, endpoint=False), indexing="ij")
    n = np.stack([np.zeros_like(a), np.cos(a), np.sin(a)], axis=-1).reshape(-1, 3)
    v = np.c_[x.reshape(-1), 0.4 * n[:, 1:]]
    w1 = np.clip((v[:, 0] - 1.5) / 1.0, 0.0, 1.0)
    return v, n, np.stack([1 - w1, w1], axis=1)


def test_clusters_follow_bones_and_axes_follow_the_limb() -> None:
    v, _, w = two_bone_arm()
    labels = cluster_vertices(w, bandwidth=0.5, min_size=8)
    assert labels.dtype == np.int32 and labels.shape == (len(v),)
    assert 2 <= labels.max() + 1 <= 4
    # pure single-bone vertices of different bones never share a cluster
    pure0, pure1 = w[:, 0] == 1.0, w[:, 1] == 1.0
    assert not set(labels[pure0]) & set(labels[pure1])
    bones = cluster_bones(w, labels)
    assert bones[labels[pure0][0]] == 0 and bones[labels[pure1][0]] == 1
    axes = cluster_axes(v, labels)
    np.testing.assert_allclose(np.linalg.norm(axes, axis=1), 1.0, atol=1e-6)
    # independent reference: numpy SVD of each cluster's centred vertices
    checked = 0
    for k in range(labels.max() + 1):
        x = v[labels == k] - v[labels == k].mean(axis=0)
        _, sv, vt = np.linalg.svd(x, full_matrices=False)
        if sv[0] > 1.1 * sv[1]:  # a well-defined principal direction (the short blend ring may not have one)
            assert abs(float(vt[0] @ axes[k])) == pytest.approx(1.0, abs=1e-5)
            checked += 1
    assert checked >= 2
    for pure in (pure0, pure1):  # the single-bone parts are long along x
        assert abs(axes[labels[pure][0], 0]) > 0.9


def test_cluster_count_is_tamed() -> None:
    rng = np.random.default_rng(0)
    w = rng.dirichlet(np.full(12, 0.2), size=300)
    labels = cluster_vertices(w, bandwidth=0.05, max_clusters=5, min_size=20)
    counts = np.bincount(labels)
    assert len(counts) <= 5 and counts.min() >= 20
    np.testing.assert_array_equal(labels, cluster_vertices(w, bandwidth=0.05, max_clusters=5, min_size=20))


def _posed_arm(angles: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Bend bone 1 about the elbow (x=2) by ``angles`` (radians, about z); LBS of normals."""
    v, n, w = two_bone_arm()
    F = len(angles)
    rot = np.zeros((F, 2, 3, 3))
    rot[:, 0] = np.eye(3)
    rot[:, 1] = Rotation.from_euler("z", angles[:, None]).as_matrix()
    mats = np.zeros((F, 2, 4, 4))
    mats[:, :, :3, :3] = rot
    mats[:, :, 3, 3] = 1
    pivot = np.array([2.0, 0, 0])
    mats[:, 1, :3, 3] = pivot - rot[:, 1] @ pivot
    blended = np.einsum("vj,fjab->fvab", w, mats)
    nrm = np.einsum("fvab,vb->fva", blended[..., :3, :3], n)
    nrm /= np.linalg.norm(nrm, axis=-1, keepdims=True)
    return v, nrm, w, mats


def test_frames_orthonormal_right_handed_and_normal_row() -> None:
    v, nrm, w, mats = _posed_arm(np.linspace(0, 1.2, 5))
    labels = cluster_vertices(w, bandwidth=0.5)
    fr = vertex_frames(nrm, mats, labels, cluster_axes(v, labels), cluster_bones(w, labels))
    assert fr.shape == (5, len(v), 3, 3) and fr.dtype == np.float32
    eye = np.einsum("...ij,...kj->...ik", fr.astype(np.float64), fr.astype(np.float64))
    np.testing.assert_allclose(eye, np.broadcast_to(np.eye(3), eye.shape), atol=1e-5)
    np.testing.assert_allclose(np.linalg.det(fr.astype(np.float64)), 1.0, atol=1e-5)
    np.testing.assert_allclose(fr[..., 2, :], nrm, atol=1e-6)


def test_frames_rotate_with_a_rigid_motion() -> None:
    """Rotating the whole posed mesh by Q (normals and all bones) maps every frame F to F Q^T."""
    v, nrm, w, mats = _posed_arm(np.array([0.0, 0.7]))
    labels = cluster_vertices(w, bandwidth=0.5)
    axes, bones = cluster_axes(v, labels), cluster_bones(w, labels)
    q = Rotation.from_euler("xyz", [0.3, -1.1, 2.0]).as_matrix()
    fr = vertex_frames(nrm, mats, labels, axes, bones).astype(np.float64)
    rot_q = np.einsum("ab,fjbc->fjac", q, mats[..., :3, :3])
    fr_q = vertex_frames(nrm @ q.T, rot_q, labels, axes, bones).astype(np.float64)
    np.testing.assert_allclose(fr_q, fr @ q.T, atol=2e-5)


def test_frames_are_temporally_coherent() -> None:
    """Bending the elbow by 2 degrees per frame turns no tangent by more than 10 degrees between frames.

    Stated bound: a tangent turns at most by (bone rotation + normal rotation) amplified by
    1 / FALLBACK_BELOW near the fallback zone; for smooth 2-degree steps we require <= 10 degrees.
    """
    angles = np.deg2rad(np.arange(0, 90, 2.0))
    v, nrm, w, mats = _posed_arm(angles)
    labels = cluster_vertices(w, bandwidth=0.5)
    fr = vertex_frames(nrm, mats, labels, cluster_axes(v, labels), cluster_bones(w, labels)).astype(np.float64)
    cos = np.sum(fr[1:, :, 0] * fr[:-1, :, 0], axis=-1)
    assert np.degrees(np.arccos(np.clip(cos, -1, 1))).max() <= 10.0


def test_single_frame_and_bad_inputs() -> None:
    v, nrm, w, mats = _posed_arm(np.array([0.3]))
    labels = cluster_vertices(w, bandwidth=0.5)
    axes, bones = cluster_axes(v, labels), cluster_bones(w, labels)
    one = vertex_frames(nrm[0], mats[0], labels, axes, bones)
    # a batch runs numpy's einsum over more axes (another inner loop); the chain after it is ~40 float64 roundings of
    # unit values amplified at most 1 / FALLBACK_BELOW, far below the float32 rounding of the result: <= 1 ulp apart
    np.testing.assert_allclose(one, vertex_frames(nrm, mats, labels, axes, bones)[0], rtol=0,
                               atol=two_path_atol(1, 1.0) + two_path_atol(40, 1 / FALLBACK_BELOW, np.float64))
    bad = nrm[0].copy()
    bad[3] = np.nan
    with pytest.raises(PrtError, match="NaN"):
        vertex_frames(bad, mats[0], labels, axes, bones)
    with pytest.raises(PrtError, match="labels"):
        vertex_frames(nrm[0], mats[0], labels[:-1], axes, bones)
    with pytest.raises(PrtError, match="skin"):
        vertex_frames(nrm[0], mats[0, :, :2, :2], labels, axes, bones)
    with pytest.raises(PrtError, match="weights"):
        cluster_vertices(np.full((4, 2), np.nan))


def test_frames_module_does_not_import_torch() -> None:
    import subprocess

    code = "import sys, prt_torch.rig.vertex_frames; assert 'torch' not in sys.modules"
    subprocess.run([sys.executable, "-c", code], check=True)


def test_builtin_walk_frames_are_coherent() -> None:
    """Frames of the built-in humanoid over its 30 fps walk.

    (a) Where the cluster axis is well off the normal (tangent-plane length >= FALLBACK_BELOW in both
    frames), the tangent turns by no more than the Dunkl-Williams bound of the projected axis:
    ``2 asin(4 (theta_bone + theta_normal) / (|t_a| + |t_a'|))`` (the projection ``a - (a.n) n`` moves
    by at most ``2 |da| + 2 |dn|``). (b) Stated angle: at least 99% of
    vertex steps turn the tangent by at most 20 degrees.
    """
    from prt_torch.rig.builtin import make_character
    from prt_torch.rig.vertex_frames import FALLBACK_BELOW

    ch = make_character(0.05)
    w = ch.dense_weights
    labels = cluster_vertices(w)
    axes, bones = cluster_axes(ch.rest_vertices, labels), cluster_bones(w, labels)
    assert labels.max() + 1 >= 10  # roughly a part per bone, not a handful of blobs
    poses = ch.pose("walk")
    _, nrm = ch.skin_mesh(poses)
    fr = vertex_frames(nrm, poses.skin, labels, axes, bones).astype(np.float64)
    t, n = fr[..., 0, :], fr[..., 2, :]
    turn = np.arccos(np.clip(np.sum(t[1:] * t[:-1], axis=-1), -1, 1))
    rot = poses.skin[:, bones, :3, :3][:, labels]  # (F, V, 3, 3) dominant-bone rotation per vertex
    rel = np.einsum("fvij,fvkj->fvik", rot[1:], rot[:-1])
    theta_b = np.arccos(np.clip((np.trace(rel, axis1=-2, axis2=-1) - 1) / 2, -1, 1))
    theta_n = np.arccos(np.clip(np.sum(n[1:] * n[:-1], axis=-1), -1, 1))
    a = np.einsum("fvij,vj->fvi", rot, axes[labels].astype(np.float64))
    a /= np.linalg.norm(a, axis=-1, keepdims=True)
    la = np.sqrt(np.clip(1 - np.sum(a * n, axis=-1) ** 2, 0, None))
    good = (la[1:] >= FALLBACK_BELOW) & (la[:-1] >= FALLBACK_BELOW)
    bound = 2 * np.arcsin(np.clip(4 * (theta_b + theta_n) / (la[1:] + la[:-1]), 0, 1))
    assert good.mean() > 0.9
    assert np.all(turn[good] <= bound[good] + 1e-3)  # + float32 rounding of the stored frames
    assert np.mean(np.degrees(turn) <= 20.0) >= 0.99


def test_fast_path_equals_reference_including_fallback_and_degenerate() -> None:
    """The player's float32 vertex-last implementation (``vertex_frames_soa``) is the same rule as the
    float64 reference: random normals and bone rotations, plus vertices whose cluster axis is (nearly)
    parallel to the normal (the fallback blend) and exactly parallel to both axes' tangent combination."""
    from prt_torch.rig.vertex_frames import fallback_axes, vertex_frames_soa

    rng = np.random.default_rng(3)
    b, v, kc, j = 3, 500, 5, 4
    axes = rng.normal(size=(kc, 3))
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    bones = rng.integers(0, j, size=kc)
    labels = rng.integers(0, kc, size=v)
    rot = Rotation.random(b * j, random_state=4).as_matrix().reshape(b, j, 3, 3)
    n = rng.normal(size=(b, v, 3))
    carried = np.einsum("bvij,vj->bvi", rot[:, bones[labels]], axes[labels])
    n[:, :50] = carried[:, :50] + 0.05 * rng.normal(size=(b, 50, 3))  # axis nearly along the normal: fallback
    n[:, 50:60] = carried[:, 50:60]  # exactly along it
    n /= np.linalg.norm(n, axis=-1, keepdims=True)
    ref = vertex_frames(n, rot, labels, axes, bones)  # (B, V, 3, 3)
    s1, s3 = np.empty((b, v), np.float32), np.empty((b, 3, v), np.float32)
    nrm = np.ascontiguousarray(n.transpose(0, 2, 1), dtype=np.float32)
    fast = vertex_frames_soa(nrm, rot[:, bones], labels.astype(np.intp), np.stack([axes, fallback_axes(axes)]), s1, s3)
    fast = fast.transpose(0, 2, 1).reshape(b, v, 3, 3)
    assert np.abs(fast - ref).max() < 2e-4

"""Linear blend skinning: numpy vs a per-vertex reference, torch vs numpy, rigid motion."""

from __future__ import annotations

import numpy as np
import torch
from scipy.spatial.transform import Rotation

from prt_torch.rig.skinning import dense_weights, skin
from prt_torch.rig.skinning_torch import lbs


def random_rig(v: int = 200, j: int = 7, k: int = 4, f: int = 3, seed: int = 0):
    rng = np.random.default_rng(seed)
    joints = np.stack([rng.choice(j, k, replace=False) for _ in range(v)])
    w = rng.random((v, k))
    w /= w.sum(1, keepdims=True)
    mats = np.tile(np.eye(4), (f, j, 1, 1))
    mats[..., :3, :3] = Rotation.random(f * j, random_state=seed).as_matrix().reshape(f, j, 3, 3)
    mats[..., :3, 3] = rng.normal(size=(f, j, 3))
    rest = rng.normal(size=(v, 3)).astype(np.float32)
    nrm = rng.normal(size=(v, 3))
    nrm = (nrm / np.linalg.norm(nrm, axis=1, keepdims=True)).astype(np.float32)
    return joints, w.astype(np.float32), mats, rest, nrm


def test_numpy_matches_per_vertex_sum() -> None:
    joints, w, mats, rest, nrm = random_rig()
    pos, n = skin(mats, dense_weights(joints, w, 7), rest, nrm)
    for f in range(mats.shape[0]):
        ref = np.zeros((len(rest), 3))
        refn = np.zeros((len(rest), 3))
        for kk in range(joints.shape[1]):
            m = mats[f, joints[:, kk]]
            ref += w[:, kk, None] * (np.einsum("vij,vj->vi", m[:, :3, :3], rest) + m[:, :3, 3])
            refn += w[:, kk, None] * np.einsum("vij,vj->vi", m[:, :3, :3], nrm)
        np.testing.assert_allclose(pos[f], ref, atol=2e-5)
        np.testing.assert_allclose(n[f], refn / np.linalg.norm(refn, axis=1, keepdims=True), atol=2e-4)
    single, _ = skin(mats[1], dense_weights(joints, w, 7), rest)
    np.testing.assert_allclose(single, pos[1], atol=1e-6)


def test_torch_matches_numpy_and_has_gradients() -> None:
    joints, w, mats, rest, nrm = random_rig(seed=1)
    pos, n = skin(mats, dense_weights(joints, w, 7), rest, nrm)
    m = torch.tensor(mats, dtype=torch.float64, requires_grad=True)
    tp, tn = lbs(m, torch.tensor(joints), torch.tensor(w), torch.tensor(rest), torch.tensor(nrm))
    np.testing.assert_allclose(tp.detach().numpy(), pos, atol=2e-5)
    np.testing.assert_allclose(tn.detach().numpy(), n, atol=2e-4)
    tp.sum().backward()
    assert m.grad is not None and torch.isfinite(m.grad).all()


def test_rigid_when_all_joints_move_together() -> None:
    joints, w, mats, rest, nrm = random_rig(seed=2)
    r = Rotation.random(random_state=5)
    m = np.eye(4)
    m[:3, :3] = r.as_matrix()
    m[:3, 3] = [1, 2, 3]
    pos, n = skin(np.tile(m, (7, 1, 1)), dense_weights(joints, w, 7), rest, nrm)
    np.testing.assert_allclose(pos, r.apply(rest) + [1, 2, 3], atol=1e-5)
    np.testing.assert_allclose(n, r.apply(nrm), atol=1e-5)

"""Per-cluster joint input selection: masks from the skinning, masked ridge vs sklearn, trained models."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest
import torch
from sklearn.linear_model import Ridge

from prt_torch.errors import PrtError
from prt_torch.fit.config import TrainConfig
from prt_torch.fit.inputs import cluster_joints, joint_inputs
from prt_torch.fit.kinds import _masked_ridge
from prt_torch.fit.train import train_dataset
from prt_torch.models import load_model

# skeleton 0 (root) -> 1 -> 2, 0 -> 3: non-root joints 1, 2, 3 own feature columns 0-5, 6-11, 12-17
PARENTS = np.array([-1, 0, 1, 0])


def test_cluster_joints_and_masks_follow_the_skinning() -> None:
    joints = np.array([[2, 1, 0, 0], [2, 0, 0, 0], [3, 0, 0, 0], [0, 3, 0, 0]])
    weights = np.array([[0.7, 0.3, 0, 0], [1.0, 0, 0, 0], [1.0, 0, 0, 0], [0.995, 0.005, 0, 0]])
    cluster = np.array([0, 0, 1, 2])
    # cluster 0: joints 2, 1 (+ parents 1, 0); cluster 1: joint 3 (+ 0); cluster 2: root only (3 is below 1%)
    assert cluster_joints(PARENTS, joints, weights, cluster) == [{0, 1, 2}, {0, 3}, {0}]
    pose = np.random.default_rng(0).normal(size=(50, 18))
    pose[:, 4] = 0.25  # a constant column is dropped
    sel = joint_inputs(pose, PARENTS, joints, weights, cluster)
    live = np.delete(np.arange(18), 4)
    np.testing.assert_array_equal(sel.live, live)
    np.testing.assert_array_equal(sel.mask[0], live < 12)
    np.testing.assert_array_equal(sel.mask[1], live >= 12)
    assert sel.mask[2].all()  # skinned by the root only: sees every input
    x = sel.reduce(pose)
    scale = np.sqrt(np.mean(pose[:, live].var(0)))  # one common scale: a barely moving joint is not blown up
    np.testing.assert_allclose(x, (pose[:, live] - pose[:, live].mean(0)) / scale, atol=1e-12)


def test_joint_inputs_bad_shapes_raise() -> None:
    with pytest.raises(PrtError, match="pose features"):
        joint_inputs(np.zeros((5, 12)), PARENTS, np.zeros((2, 4), int), np.zeros((2, 4)), np.zeros(2, int))
    with pytest.raises(PrtError, match="skinning"):
        cluster_joints(PARENTS, np.zeros((3, 4), int), np.zeros((2, 4)), np.zeros(2, int))


def test_masked_ridge_equals_sklearn_on_the_selected_columns() -> None:
    rng = np.random.default_rng(1)
    x, z = rng.normal(size=(40, 6)), rng.normal(size=(40, 2, 3))
    in_mask = np.array([[1, 1, 0, 0, 1, 0], [0, 0, 1, 1, 1, 1]], dtype=bool)
    alpha = np.array([0.5, 3.0])
    w, b = _masked_ridge(x, z, alpha, in_mask)
    for g in range(2):
        ref = Ridge(alpha=alpha[g]).fit(x[:, in_mask[g]], z[:, g])
        np.testing.assert_allclose(w[in_mask[g], g], ref.coef_.T, atol=1e-10)
        np.testing.assert_allclose(b[g], ref.intercept_, atol=1e-10)
        assert not w[~in_mask[g], g].any()


def _with_character(synthetic_dataset: Path, tmp_path: Path) -> Path:
    """A copy of the synthetic dataset (12 pose columns = joints 1, 2 under root 0) with a character.npz
    whose cluster c is skinned by joint 1 + c % 2."""
    import zarr

    ds = tmp_path / "dataset.zarr"
    shutil.copytree(synthetic_dataset, ds)
    cluster = np.asarray(zarr.open_group(str(ds), mode="r")["cluster"][:])
    joints = np.zeros((len(cluster), 4), np.int64)
    joints[:, 0] = 1 + cluster % 2
    weights = np.zeros((len(cluster), 4))
    weights[:, 0] = 1.0
    np.savez(tmp_path / "character.npz", parents=np.array([-1, 0, 0]), joints=joints, weights=weights)
    return ds


def test_training_with_joint_inputs(synthetic_dataset: Path, tmp_path: Path) -> None:
    cfg = TrainConfig(kinds=["linear", "mlp"], input_selection="joints", alphas=[1e-2, 1.0], mlp_alphas=[1.0],
                      neurons=[4], cv_iter=30, max_iter=60)
    with pytest.raises(PrtError, match="character.npz"):
        train_dataset(synthetic_dataset, tmp_path / "nochar", cfg)
    ds = _with_character(synthetic_dataset, tmp_path)
    metrics = train_dataset(ds, tmp_path / "run", cfg)["models"]
    for kind in ("linear", "mlp"):
        assert metrics[kind]["train"]["vis_rel_err"] < 1.0
    mlp, lin = load_model(tmp_path / "run", "mlp"), load_model(tmp_path / "run", "linear")
    # cluster g may only use joint 1 + g % 2 (its parent is the root): columns 6 (g % 2) .. +6
    col_joint = np.arange(12) // 6
    for g in range(mlp.regressor.hidden_weight.shape[0]):
        outside = torch.as_tensor(col_joint != g % 2)
        assert mlp.regressor.hidden_weight[g][:, outside].abs().max() == 0
        assert mlp.regressor.hidden_weight[g][:, ~outside].abs().max() > 0
        assert lin.regressor.weight[outside, g].abs().max() == 0
    x = torch.randn(3, 12)
    x2 = x.clone()
    x2[:, col_joint == 1] += 1.0  # moving joint 2 leaves the clusters skinned by joint 1 unchanged
    y, y2 = mlp(x), mlp(x2)
    cluster = np.asarray(__import__("zarr").open_group(str(ds), mode="r")["cluster"][:])
    same = torch.as_tensor(cluster % 2 == 0)
    torch.testing.assert_close(y[:, same], y2[:, same])
    assert (y[:, ~same] - y2[:, ~same]).abs().max() > 0

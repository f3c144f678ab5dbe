"""Ridge against scikit-learn; blocked folds."""

from __future__ import annotations

import numpy as np
import pytest
from sklearn.linear_model import Ridge

from prt_torch.errors import PrtError
from prt_torch.fit.folds import blocked_folds
from prt_torch.fit.ridge import fit_ridge_per_group, ridge_cv, ridge_path


def test_ridge_path_matches_sklearn() -> None:
    rng = np.random.default_rng(0)
    x, y = rng.normal(size=(40, 6)), rng.normal(size=(40, 3, 2))
    alphas = np.array([1e-3, 0.5, 20.0])
    w, b = ridge_path(x, y, alphas)
    for i, a in enumerate(alphas):
        sk = Ridge(alpha=a).fit(x, y.reshape(40, -1))
        np.testing.assert_allclose(w[i], sk.coef_.T.reshape(6, 3, 2), atol=1e-10)
        np.testing.assert_allclose(b[i], sk.intercept_.reshape(3, 2), atol=1e-10)
    w0, _ = ridge_path(x, y, np.array([0.0]))  # unregularised: ordinary least squares
    ref = np.linalg.lstsq(np.c_[x, np.ones(40)], y.reshape(40, -1), rcond=None)[0][:6]
    np.testing.assert_allclose(w0[0].reshape(6, -1), ref, atol=1e-10)


def test_per_group_alpha_and_cv_choose_columns() -> None:
    rng = np.random.default_rng(1)
    x, y = rng.normal(size=(30, 4)), rng.normal(size=(30, 3, 2))
    w, b = fit_ridge_per_group(x, y, np.array([0.1, 5.0, 0.1]))
    for g, a in enumerate([0.1, 5.0, 0.1]):
        sk = Ridge(alpha=a).fit(x, y[:, g])
        np.testing.assert_allclose(w[:, g], sk.coef_.T, atol=1e-10)
    folds = np.repeat(np.arange(3), 10)
    cv = ridge_cv(x, y, np.ones((3, 2), bool), folds, np.array([0.1, 5.0]))
    ref = 0.0
    for k in range(3):  # alpha 5 on group 1, by hand with sklearn
        tr = folds != k
        sk = Ridge(alpha=5.0).fit(x[tr], y[tr, 1])
        ref += ((sk.predict(x[~tr]) - y[~tr, 1]) ** 2).sum()
    assert cv[1, 1] == pytest.approx(ref, rel=1e-10)


def test_blocked_folds_whole_clips_or_contiguous_ranges() -> None:
    clip = np.repeat(np.arange(5), [30, 25, 20, 20, 15])
    frame = np.concatenate([np.arange(n) for n in [30, 25, 20, 20, 15]])
    f = blocked_folds(clip, frame, 4)
    assert set(f) == {0, 1, 2, 3}
    for c in range(5):  # each clip lies in one fold
        assert len(set(f[clip == c])) == 1
    # one long clip: contiguous frame ranges, so validation frames' neighbours are mostly validation frames
    f1 = blocked_folds(np.zeros(100, int), np.arange(100), 4)
    assert np.count_nonzero(np.diff(f1)) == 3
    assert np.bincount(f1).min() == 25
    with pytest.raises(PrtError, match="cannot make"):
        blocked_folds(np.zeros(3, int), np.arange(3), 4)


def test_train_only_frames_are_never_validated() -> None:
    """``cv_validate: clips``: the train-only frames (random poses) get fold -1, the k folds are made from the
    motion frames alone, and ridge CV's error equals a hand-written loop that validates on motion frames only
    (with sklearn Ridge fits) while always training on the train-only frames."""
    rng = np.random.default_rng(5)
    clip_id = np.repeat(np.arange(6), [30, 25, 20, 15, 10, 40])
    frame_index = np.concatenate([np.arange(n) for n in (30, 25, 20, 15, 10, 40)])
    train_only = clip_id == 5
    folds = blocked_folds(clip_id, frame_index, 4, train_only)
    assert np.all(folds[train_only] == -1)
    np.testing.assert_array_equal(folds[~train_only], blocked_folds(clip_id[~train_only], frame_index[~train_only], 4))
    assert sorted(np.unique(folds[~train_only])) == [0, 1, 2, 3]
    x = rng.normal(size=(len(clip_id), 5))
    y = x @ rng.normal(size=(5, 1, 3)).reshape(5, 3) + 0.1 * rng.normal(size=(len(clip_id), 3))
    alphas = np.array([0.1, 10.0])
    got = ridge_cv(x, y[:, None, :], np.ones((1, 3)), folds, alphas)[:, 0]
    want = np.zeros(2)
    for a, alpha in enumerate(alphas):
        for k in range(4):
            tr, va = folds != k, folds == k
            pred = Ridge(alpha=alpha).fit(x[tr], y[tr]).predict(x[va])
            want[a] += ((pred - y[va]) ** 2).sum()
    np.testing.assert_allclose(got, want, rtol=1e-8)
    with pytest.raises(PrtError, match="validation frames"):
        blocked_folds(clip_id, frame_index, 4, np.ones_like(train_only))

"""Blocked k-fold cross-validation splits.

Neighbouring animation frames are nearly identical, so random folds leak: a held-out frame's
neighbours are in the training fold. Folds are therefore contiguous blocks: whole clips when
there are at least ``k`` training clips (balanced greedily by frame count), else ``k`` contiguous
frame ranges of the (clip, frame)-ordered training set.
"""

from __future__ import annotations

import numpy as np

from prt_torch.errors import check
from prt_torch.shapes import check_shape


def blocked_folds(clip_id: np.ndarray, frame_index: np.ndarray, k: int = 4,
                  train_only: np.ndarray | None = None) -> np.ndarray:
    """Fold number ``(F,)`` int64 in ``[0, k)`` of each frame; every fold is non-empty.

    ``train_only (F,)`` bool: frames that are never validated on (fold ``-1``: in every training fold);
    the ``k`` folds are made from the other frames.
    """
    clip_id = np.asarray(clip_id)
    frame_index = np.asarray(frame_index)
    if train_only is not None:
        train_only = np.asarray(train_only, dtype=bool)
        check_shape(train_only, clip_id.shape, name="folds: train_only")
        check(int((~train_only).sum()) >= k, f"folds: {int((~train_only).sum())} validation frames cannot make "
                                             f"{k} folds (cv_validate: clips needs motion clips in training)")
        out = np.full(clip_id.shape[0], -1, dtype=np.int64)
        out[~train_only] = blocked_folds(clip_id[~train_only], frame_index[~train_only], k)
        return out
    n = clip_id.shape[0]
    dims = check_shape(clip_id, "F", name="folds: clip_id")
    check_shape(frame_index, "F", name="folds: frame_index", dims=dims)
    check(k >= 2, f"folds: need k >= 2, got {k}")
    check(n >= k, f"folds: {n} frames cannot make {k} folds")
    clips, counts = np.unique(clip_id, return_counts=True)
    fold = np.empty(n, dtype=np.int64)
    if len(clips) >= k and counts.max() <= 2 * n / k:
        load = np.zeros(k)
        for c in clips[np.argsort(-counts, kind="stable")]:
            f = int(np.argmin(load))
            fold[clip_id == c] = f
            load[f] += np.count_nonzero(clip_id == c)
        return fold
    order = np.lexsort((frame_index, clip_id))
    fold[order] = (np.arange(n) * k) // n
    return fold

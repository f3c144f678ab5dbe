"""Which frames are scored or rendered: evenly spaced picks (:func:`prt_torch.metrics.evenly_spaced_indices`)."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from prt_torch.metrics import evenly_spaced_indices


def evenly_spaced(n_total: int, n_pick: int, must: Sequence[int] = ()) -> np.ndarray:
    """``min(n_pick, n_total)`` sorted distinct indices in ``[0, n_total)``, evenly spaced, including ``must``."""
    if n_total <= 0 or n_pick <= 0:
        return np.zeros(0, dtype=np.int64)
    base = evenly_spaced_indices(n_total, min(n_pick, n_total))
    idx = np.unique(np.concatenate([base, np.asarray(must, dtype=np.int64)]))
    if len(idx) > n_pick and len(must):
        keep = set(int(m) for m in must)
        extra = [int(i) for i in idx if int(i) not in keep][: max(0, n_pick - len(keep))]
        idx = np.array(sorted(keep | set(extra)), dtype=np.int64)
    return idx

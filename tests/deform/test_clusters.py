"""k-means clusters of rest positions: deterministic, renumbered, Lloyd fixpoint, few-vertex cases."""

from __future__ import annotations

import numpy as np
import pytest

from prt_torch.deform.clusters import spatial_clusters
from prt_torch.errors import PrtError
from tests.deform.sheets import sheet


def test_deterministic_renumbered_and_a_kmeans_fixpoint() -> None:
    v, _ = sheet(20, 15)
    v[:, 2] = 0.1 * np.sin(4 * v[:, 0])
    a = spatial_clusters(v, 8, seed=3)
    assert a.dtype == np.int32 and a.shape == (len(v),)
    np.testing.assert_array_equal(a, spatial_clusters(v, 8, seed=3))
    assert set(a.tolist()) == set(range(8))
    _, first = np.unique(a, return_index=True)
    assert np.all(np.diff(first) > 0)  # numbered in order of first appearance
    # Lloyd fixpoint (independent of scikit-learn): every vertex is nearest to its own cluster mean
    means = np.stack([v[a == k].mean(axis=0) for k in range(8)])
    d = np.linalg.norm(v[:, None] - means[None], axis=-1)
    assert np.all(d[np.arange(len(v)), a] <= d.min(axis=1) + 1e-9)


def test_fewer_vertices_than_clusters() -> None:
    v = np.array([[0.0, 0, 0], [1, 0, 0], [1, 0, 0], [0, 2, 0]])
    lab = spatial_clusters(v, 10, seed=0)
    np.testing.assert_array_equal(lab, [0, 1, 1, 2])
    np.testing.assert_array_equal(spatial_clusters(v, 1, seed=0), 0)


def test_bad_inputs() -> None:
    v, _ = sheet(3, 3)
    with pytest.raises(PrtError, match="n_clusters"):
        spatial_clusters(v, 0, seed=0)
    v[0, 0] = np.nan
    with pytest.raises(PrtError, match="NaN"):
        spatial_clusters(v, 2, seed=0)
    with pytest.raises(PrtError, match=r"\(V, 3\)"):
        spatial_clusters(v[:, :2], 2, seed=0)

"""Vertex clusters without bones: k-means on rest positions (seed 003 section 5.2, non-articulated case).

numpy + scikit-learn only.
"""

from __future__ import annotations

import numpy as np

from prt_torch.errors import check
from prt_torch.shapes import check_shape


def spatial_clusters(rest_vertices: np.ndarray, n_clusters: int, seed: int) -> np.ndarray:
    """K-means clusters of the rest positions.

    ``sklearn.cluster.KMeans(n_clusters, random_state=seed, n_init=4)`` on the ``(V, 3)`` rest positions
    (float64, single-threaded BLAS): deterministic for a seed. When there are fewer distinct positions than
    ``n_clusters``, that many clusters are made (every distinct position its own cluster). Labels are then
    renumbered in order of first appearance along the vertex index (vertex 0 is in cluster 0, the first vertex
    not in cluster 0 starts cluster 1, ...), so the numbering does not depend on k-means' internal order.

    Args:
        rest_vertices: ``(V, 3)`` rest positions, finite, ``V >= 1``.
        n_clusters: wanted number of clusters, ``>= 1``.
        seed: k-means seed.

    Returns:
        ``(V,)`` int32 labels ``0 .. K-1`` with ``K = min(n_clusters, distinct positions)``; every label is used.
    """
    from sklearn.cluster import KMeans
    from threadpoolctl import threadpool_limits

    x = np.asarray(rest_vertices, dtype=np.float64)
    check_shape(x, "V 3", name="rest vertices")
    check(x.shape[0] > 0, f"rest vertices must have shape (V, 3) with V > 0, got {x.shape}")
    check(bool(np.isfinite(x).all()), "rest vertices contain NaN or inf")
    check(int(n_clusters) >= 1, f"n_clusters must be >= 1, got {n_clusters}")
    k = min(int(n_clusters), int(np.unique(x, axis=0).shape[0]))
    if k == 1:
        return np.zeros(x.shape[0], dtype=np.int32)
    with threadpool_limits(limits=1):
        labels = KMeans(n_clusters=k, random_state=int(seed), n_init=4).fit_predict(x)
    used, first = np.unique(labels, return_index=True)
    remap = np.empty(int(labels.max()) + 1, dtype=np.int32)
    remap[used[np.argsort(first, kind="stable")]] = np.arange(used.size, dtype=np.int32)
    return remap[labels]

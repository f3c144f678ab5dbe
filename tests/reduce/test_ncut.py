"""Normalized cut (seed 001 section 3) against scikit-learn's spectral clustering, brute force and eq. 3 by hand."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp
from sklearn.cluster import SpectralClustering
from sklearn.metrics import adjusted_rand_score

from prt_torch.errors import PrtError
from prt_torch.s001 import ncut


def _blocks(sizes: list[int], inter: float, seed: int = 0) -> np.ndarray:
    """Symmetric weights: dense blocks (U(0.5, 1)) weakly linked (U(0, inter)), zero diagonal."""
    rng = np.random.default_rng(seed)
    n = sum(sizes)
    w = rng.uniform(0.0, inter, (n, n))
    start = 0
    for s in sizes:
        w[start:start + s, start:start + s] = rng.uniform(0.5, 1.0, (s, s))
        start += s
    w = (w + w.T) / 2
    np.fill_diagonal(w, 0.0)
    return w


def _ncut_brute(w: np.ndarray, mask: np.ndarray) -> float:
    """Eq. 1 written out: cut / assoc(A, V) + cut / assoc(B, V)."""
    cut = w[np.ix_(mask, ~mask)].sum()
    return cut / w[mask].sum() + cut / w[~mask].sum()


def test_bisect_matches_sklearn_spectral_clustering() -> None:
    w = _blocks([15, 15], inter=0.05, seed=1)
    perm = np.random.default_rng(2).permutation(30)
    w = w[np.ix_(perm, perm)]
    ours = ncut.ncut_bisect(sp.csr_matrix(w))
    ref = SpectralClustering(n_clusters=2, affinity="precomputed", random_state=0).fit_predict(w)
    assert adjusted_rand_score(ref, ours.astype(int)) == 1.0
    assert ours.sum() == 15 and not ours[0]


def test_bisect_is_the_brute_force_minimum_normalized_cut() -> None:
    w = _blocks([6, 6], inter=0.15, seed=3)
    n = w.shape[0]
    best = min(_ncut_brute(w, np.array([(i >> b) & 1 for b in range(n)], dtype=bool))
               for i in range(1, 2 ** (n - 1)))  # every non-trivial split, node n-1 always in B
    ours = ncut.ncut_bisect(w)
    assert _ncut_brute(w, ours) == pytest.approx(best, rel=1e-12)
    assert ncut.ncut_value(w, ours) == pytest.approx(best, rel=1e-12)


def test_fiedler_vector_solves_the_generalized_problem_and_sparse_path_agrees(monkeypatch) -> None:
    w = _blocks([40, 30, 50], inter=0.2, seed=4)
    d = w.sum(1)
    y = ncut.fiedler_vector(w)
    lam2 = np.sort(np.linalg.eigvalsh(np.eye(len(d)) - w / np.sqrt(np.outer(d, d))))[1]  # normalized Laplacian
    np.testing.assert_allclose((np.diag(d) - w) @ y, lam2 * d * y, atol=1e-9 * np.abs(d * y).max())
    dense = ncut.ncut_bisect(w)
    monkeypatch.setattr(ncut, "DENSE_MAX", 10)  # force eigsh on D^-1/2 W D^-1/2
    assert np.array_equal(ncut.ncut_bisect(sp.csr_matrix(w)), dense)


def test_disconnected_graph_splits_between_components() -> None:
    w = np.zeros((10, 10))
    w[:5, :5] = 1.0
    w[5:, 5:] = 2.0
    np.fill_diagonal(w, 0.0)
    perm = np.random.default_rng(5).permutation(10)
    m = ncut.ncut_bisect(w[np.ix_(perm, perm)])
    assert set(m[perm < 5]) == {m[perm < 5][0]} and set(m[perm >= 5]) == {not m[perm < 5][0]}


def test_recursive_leaves_bounded_deterministic_and_recover_planted_groups() -> None:
    w = _blocks([4] * 8, inter=0.05, seed=6)
    perm = np.random.default_rng(7).permutation(32)
    wp = w[np.ix_(perm, perm)]
    labels = ncut.recursive_ncut(sp.csr_matrix(wp), leaf_size=4)
    assert adjusted_rand_score(perm // 4, labels) == 1.0
    assert np.array_equal(labels, ncut.recursive_ncut(wp, leaf_size=4))
    rng = np.random.default_rng(8)
    a = rng.random((37, 37))
    labels = ncut.recursive_ncut((a + a.T) / 2, leaf_size=4)
    sizes = np.bincount(labels)
    assert sizes.max() <= 4 and sizes.min() >= 2 and sizes.sum() == 37


def test_segment_affinity_is_eq3_by_hand() -> None:
    rng = np.random.default_rng(9)
    t = rng.normal(size=(7, 5, 4, 4))  # 7 poses, 5 vertices, 4 x 4 matrices
    bones = rng.normal(size=(7, 3, 3, 4))
    var_t = np.var(t.reshape(7, -1), axis=0).sum()  # variance of the segment's transfer matrices over poses
    var_p = np.var(bones.reshape(7, -1), axis=0).sum()
    ref = np.zeros((7, 7))
    for i in range(7):
        for j in range(7):
            st = sum(np.linalg.norm(t[i, l] - t[j, l], "fro") ** 2 for l in range(5))
            sp_ = sum(np.linalg.norm(bones[i, b] - bones[j, b], "fro") ** 2 for b in range(3))
            ref[i, j] = 0.0 if i == j else np.exp(-st / (2 * 1.0 * var_t) - sp_ / (2 * 2.0 * var_p))
    np.testing.assert_allclose(ncut.segment_affinity(t, bones).toarray(), ref, rtol=1e-10, atol=1e-14)


def test_streamed_segment_distances_and_cluster_segments() -> None:
    zarr = pytest.importorskip("zarr")
    rng = np.random.default_rng(10)
    p, v = 16, 30
    data = rng.normal(size=(p, v, 3, 3)).astype(np.float32)
    z = zarr.create_array(store=zarr.storage.MemoryStore(), shape=data.shape, chunks=(4, 7, 3, 3), dtype="float32")
    z[:] = data
    seg = rng.integers(0, 3, v)
    d = ncut.segment_sq_dists_streamed(z, seg, block=7)
    for k in range(3):
        x = data[:, seg == k].reshape(p, -1).astype(np.float64)
        np.testing.assert_allclose(d[k], ((x[:, None] - x[None]) ** 2).sum(-1), rtol=1e-9, atol=1e-9)
    groups = ncut.cluster_segments(z, seg, rng.normal(size=(p, 4, 3, 4)), leaf_size=4)
    assert groups.shape == (3, p)
    for k in range(3):
        assert np.bincount(groups[k]).tolist() == [4, 4, 4, 4]


@pytest.mark.parametrize("w, match", [
    (np.zeros((0, 0)), "empty graph"),
    (np.zeros((4, 4)), "no edge"),
    (np.ones((3, 4)), "square"),
    (np.full((3, 3), np.nan), "NaN"),
    (-np.ones((3, 3)), "non-negative"),
    (np.triu(np.ones((3, 3)), 1), "symmetric"),
])
def test_bad_graphs_raise_one_line_errors(w: np.ndarray, match: str) -> None:
    with pytest.raises(PrtError, match=match) as e:
        ncut.ncut_bisect(w)
    assert "\n" not in str(e.value)


def test_bad_affinity_inputs_raise() -> None:
    with pytest.raises(PrtError, match="bones"):
        ncut.segment_affinity(np.zeros((4, 2, 3)), np.zeros((5, 2, 3)))
    with pytest.raises(PrtError, match="NaN"):
        ncut.segment_affinity(np.full((4, 2, 3), np.nan), np.zeros((4, 2, 3)))
    with pytest.raises(PrtError, match="leaf_size"):
        ncut.recursive_ncut(np.ones((3, 3)), leaf_size=0)


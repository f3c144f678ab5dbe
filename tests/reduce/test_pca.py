"""PCA and output PCAs against scikit-learn and the Eckart-Young identity."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from sklearn.decomposition import PCA as SkPCA

from prt_torch.errors import PrtError
from prt_torch.models import OutputUnprojection
from prt_torch.reduce import PCA, ClusterPCA, GlobalOutputPCA, components_for_variance
from tests.tolerance import assert_bitwise


def _data(n: int = 60, d: int = 10, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return rng.normal(size=(n, 4)) @ rng.normal(size=(4, d)) * 3 + 0.1 * rng.normal(size=(n, d)) + 5.0


def test_pca_matches_sklearn() -> None:
    x = _data()
    p = PCA.fit(x, n_components=4)
    sk = SkPCA(n_components=4).fit(x)
    np.testing.assert_allclose(p.explained[:4], sk.explained_variance_, rtol=1e-10)
    # components agree up to sign
    dots = np.abs(np.sum(p.components * sk.components_, axis=1))
    np.testing.assert_allclose(dots, 1.0, atol=1e-8)
    np.testing.assert_allclose(p.expand(p.reduce(x)), sk.inverse_transform(sk.transform(x)), atol=1e-9)
    assert p.retained == pytest.approx(sk.explained_variance_ratio_.sum(), rel=1e-10)


def test_retained_variance_is_minimal() -> None:
    x = _data()
    for v in (0.5, 0.9, 0.99, 0.999):
        p = PCA.fit(x, variance=v)
        frac = np.cumsum(p.explained) / p.explained.sum()
        k = p.n_components
        assert frac[k - 1] >= v - 1e-12
        assert k == 1 or frac[k - 2] < v
    assert components_for_variance(np.array([3.0, 1.0]), 0.75) == 1


def test_whitened_inputs_have_unit_variance() -> None:
    x = _data()
    p = PCA.fit(x, variance=0.95, whiten=True)
    r = p.reduce(x)
    np.testing.assert_allclose(r.var(axis=0, ddof=1), 1.0, rtol=1e-9)
    np.testing.assert_allclose(p.expand(r), PCA.fit(x, variance=0.95).expand(PCA.fit(x, variance=0.95).reduce(x)),
                               atol=1e-9)


def _vis(f: int = 40, v: int = 30, c: int = 9, seed: int = 1) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    y = rng.normal(size=(f, 3)) @ rng.normal(size=(3, v * c)) + 0.2 * rng.normal(size=(f, v * c))
    cluster = rng.integers(0, 4, size=v) * 7  # non-contiguous labels
    return y.reshape(f, v, c), cluster


def test_cluster_pca_eckart_young_and_exact_at_full_variance() -> None:
    y, cluster = _vis()
    full = ClusterPCA.fit(y, cluster, variance=1.0)
    np.testing.assert_allclose(full.expand(full.reduce(y)), y, atol=1e-9)
    red = full.truncated(0.8)
    err = ((red.expand(red.reduce(y)) - y) ** 2).sum()
    # Eckart-Young: the squared residual is (N - 1) times the sum of the dropped eigenvalues
    dropped = sum(p.explained[p.n_components:].sum() for p in red.pcas)
    assert err == pytest.approx((y.shape[0] - 1) * dropped, rel=1e-8)
    for p, q in zip(red.pcas, ClusterPCA.fit(y, cluster, variance=0.8).pcas, strict=True):
        assert p.n_components == q.n_components


def test_padded_unprojection_matches_numpy_expand() -> None:
    y, cluster = _vis()
    cp = ClusterPCA.fit(y, cluster, variance=0.9)
    z = cp.reduce(y)
    assert z.shape == (y.shape[0], cp.n_groups, cp.width)
    assert np.all(z[:, ~cp.mask] == 0)
    basis, gather, mean = cp.padded_basis()
    mod = OutputUnprojection(basis, gather, mean, y.shape[1], y.shape[2]).double()
    mod.basis = mod.basis.double()
    mod.mean = mod.mean.double()
    got = mod(torch.as_tensor(z)).numpy()
    np.testing.assert_allclose(got, cp.expand(z), atol=1e-5)


def test_global_output_pca_roundtrip() -> None:
    y, _ = _vis()
    g = GlobalOutputPCA.fit(y, variance=1.0)
    z = g.reduce(y)
    assert z.shape == (y.shape[0], 1, g.width)
    np.testing.assert_allclose(g.expand(z), y, atol=1e-9)
    g2 = GlobalOutputPCA.fit(y, variance=0.9)
    assert g2.pca.n_components < g.pca.n_components


@pytest.mark.parametrize(
    ("call", "match"),
    [
        (lambda: PCA.fit(np.zeros((5,))), "expected a \\(N, D\\)"),
        (lambda: PCA.fit(np.full((5, 3), np.nan)), "NaN"),
        (lambda: PCA.fit(np.ones((5, 3)), variance=1.5), "retained variance"),
        (lambda: PCA.fit(np.ones((5, 3)), n_components=2).reduce(np.ones((2, 4))), "expected \\(N, 3\\)"),
        (lambda: ClusterPCA.fit(np.ones((4, 3, 5)), np.zeros(3, int)), "order\\*\\*2"),
        (lambda: ClusterPCA.fit(np.ones((4, 3, 4)), np.zeros(2, int)), "cluster"),
        (lambda: ClusterPCA.fit(np.ones((4, 3, 4)), np.zeros(3)), "integer"),
    ],
)
def test_bad_inputs_raise(call, match: str) -> None:  # noqa: ANN001
    with pytest.raises(PrtError, match=match):
        call()


def test_global_unprojection_matches_numpy_expand() -> None:
    from prt_torch.models import GlobalUnprojection

    y, _ = _vis()
    g = GlobalOutputPCA.fit(y, variance=0.9)
    z = g.reduce(y)
    p = g.pca
    mean = np.repeat(p.mean[:, None], y.shape[2], axis=1).reshape(-1)
    mod = GlobalUnprojection(p.components * p.scale[:, None], mean, y.shape[1], y.shape[2])
    got = mod(torch.as_tensor(z, dtype=torch.float32)).numpy()
    np.testing.assert_allclose(got, g.expand(z), atol=1e-4)


def test_cluster_pca_max_components_caps_each_cluster_like_sklearn() -> None:
    """``max_components`` keeps min(variance count, cap) components per cluster; the capped reconstruction of each
    cluster equals scikit-learn's PCA with that many components."""
    rng = np.random.default_rng(3)
    f, v, c = 40, 30, 4
    y = rng.normal(size=(f, v, c)) @ np.diag([1.0, 0.5, 0.3, 0.1])
    cluster = np.repeat(np.arange(3), 10)
    free = ClusterPCA.fit(y, cluster, variance=0.99)
    capped = ClusterPCA.fit(y, cluster, variance=0.99, max_components=5)
    np.testing.assert_array_equal(capped.dims, np.minimum(free.dims, 5))
    assert (free.dims > 5).all()  # the cap binds
    rec = capped.expand(capped.reduce(y))
    for g in range(3):
        m = cluster == g
        sk = SkPCA(n_components=5).fit(y[:, m].reshape(f, -1))
        ref = sk.inverse_transform(sk.transform(y[:, m].reshape(f, -1))).reshape(f, -1, c)
        np.testing.assert_allclose(rec[:, m], ref, atol=1e-8)
    with pytest.raises(PrtError, match="max_components"):
        ClusterPCA.fit(y, cluster, variance=0.99, max_components=0)


def test_pca_max_components_caps_the_variance_count_like_sklearn() -> None:
    """``max_components`` keeps min(variance count, cap) components (the input projection's size cap); capped, the
    reconstruction equals scikit-learn's PCA with that many components; a cap above the count changes nothing."""
    x = _data(d=12)
    free = PCA.fit(x, variance=0.999)
    assert free.n_components > 2  # the cap below binds
    capped = PCA.fit(x, variance=0.999, max_components=2)
    assert capped.n_components == 2
    sk = SkPCA(n_components=2).fit(x)
    np.testing.assert_allclose(capped.expand(capped.reduce(x)), sk.inverse_transform(sk.transform(x)), atol=1e-9)
    assert capped.retained == pytest.approx(sk.explained_variance_ratio_.sum(), rel=1e-10)
    loose = PCA.fit(x, variance=0.999, max_components=free.n_components + 3)
    assert_bitwise(loose.components, free.components, why='the same SVD of the same data; the cap only truncates')
    with pytest.raises(PrtError, match="max_components"):
        PCA.fit(x, variance=0.9, max_components=0)

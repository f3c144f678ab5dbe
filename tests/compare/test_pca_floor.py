"""``pca_floor`` (the oracle row of prt compare): its reduce/expand against the training side's own ClusterPCA
(numpy SVD per cluster), on data the basis was not fitted to."""

from __future__ import annotations

import numpy as np
import torch

from prt_torch.compare.methods import METHODS
from prt_torch.compare.methods.pca_floor import cluster_reduce
from prt_torch.models import OutputUnprojection
from prt_torch.reduce import ClusterPCA


def test_cluster_reduce_then_expand_is_cluster_pca_projection() -> None:
    rng = np.random.default_rng(4)
    f, v, c = 50, 24, 9
    cluster = rng.integers(0, 3, size=v) * 5  # non-contiguous labels, uneven cluster sizes
    y = 0.05 * rng.normal(size=(f, v, c))
    for label, rank in ((0, 2), (5, 5), (10, 7)):  # a different rank per cluster: different component counts
        m = cluster == label
        y[:, m] += (rng.normal(size=(f, rank)) @ rng.normal(size=(rank, int(m.sum()) * c))).reshape(f, -1, c)
    pca = ClusterPCA.fit(y[:40], cluster, variance=0.9)
    assert pca.dims.min() < pca.width  # padded rows exist: the pinv must give them zero coefficients
    basis, gather, mean = pca.padded_basis()
    out = OutputUnprojection(basis, gather, mean, v, c)
    test = y[40:]  # frames the basis was not fitted to
    z = cluster_reduce(basis, gather, mean, test.reshape(len(test), -1))
    with torch.no_grad():
        rec = out(torch.from_numpy(z.astype(np.float32))).numpy()
    ref = pca.expand(pca.reduce(test))
    np.testing.assert_allclose(rec, ref, atol=1e-4 * np.abs(ref).max())
    # a frame inside the span comes back exactly; the residual of another is orthogonal to the span
    inside = pca.expand(pca.reduce(test[:1]))
    z_in = cluster_reduce(basis, gather, mean, inside.reshape(1, -1))
    with torch.no_grad():
        np.testing.assert_allclose(out(torch.from_numpy(z_in.astype(np.float32))).numpy(), inside,
                                   atol=1e-4 * np.abs(inside).max())
    assert METHODS["pca_floor"].default is False  # an oracle: opt-in, never a run-time row by default


def test_pca_floor_on_a_run_bounds_every_learned_model(small_run) -> None:  # noqa: ANN001
    """On a trained run's held-out frames: the oracle is the orthogonal projection onto the affine span every model
    of the run outputs in (same output basis and mean), so its error is at most each model's, frame by frame."""
    from prt_torch.compare.run import heldout_frames, load_compare_run
    from prt_torch.metrics import vis_rel_err
    from prt_torch.models.visibility import load_model

    ctx = load_compare_run(small_run)
    fs = heldout_frames(ctx, max_frames=4)
    assert METHODS["pca_floor"].available(ctx) and fs.baked_visibility is not None
    floor = METHODS["pca_floor"]()
    floor.prepare(ctx, fs)
    got = floor.visibility(fs.batch(np.arange(fs.n_frames)))
    truth = fs.baked_visibility
    assert got.shape == truth.shape
    kinds = [k for k in ("linear", "quadratic", "mlp") if ctx.run.model_path(k).is_file()]
    assert kinds
    for kind in kinds:
        with torch.no_grad():
            pred = load_model(small_run, kind).predict(fs.features).numpy()
        for f in range(fs.n_frames):
            assert vis_rel_err(got[f:f + 1], truth[f:f + 1]) <= vis_rel_err(pred[f:f + 1], truth[f:f + 1]) + 1e-6
    assert 0 < vis_rel_err(got, truth) < 1

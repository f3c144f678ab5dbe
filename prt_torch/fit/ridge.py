"""Ridge (Tikhonov) regression batched over output groups and a grid of regularisers.

Minimises ``||F_c W - Z_c||^2 + alpha ||W||^2`` (seed 000 section 4.1 with ``alpha`` in place of
``alpha^2``; ``F_c``, ``Z_c`` centred, so the intercept is not penalised). One thin SVD of the
shared design matrix serves every alpha and every group: ``W = V diag(s / (s^2 + alpha)) U^T Z_c``.
All float64.
"""

from __future__ import annotations

import numpy as np

from prt_torch.errors import check


def ridge_path(features: np.ndarray, targets: np.ndarray, alphas: np.ndarray,
               sample_mask: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Fit every ``alpha``: ``features (N, p)``, ``targets (N, ...)`` -> ``weight (A, p, ...)``,
    ``bias (A, ...)``; only rows where ``sample_mask`` is true are used."""
    f = np.asarray(features, dtype=np.float64)
    y = np.asarray(targets, dtype=np.float64)
    alphas = np.asarray(alphas, dtype=np.float64)
    check(f.ndim == 2 and y.shape[0] == f.shape[0], f"ridge: features {f.shape} and targets {y.shape} disagree")
    check(bool((alphas >= 0).all()), "ridge: alphas must be >= 0")
    if sample_mask is not None:
        f, y = f[sample_mask], y[sample_mask]
    tail = y.shape[1:]
    y2 = y.reshape(y.shape[0], -1)
    fm, ym = f.mean(axis=0), y2.mean(axis=0)
    u, s, vt = np.linalg.svd(f - fm, full_matrices=False)
    uty = u.T @ (y2 - ym)  # (r, T)
    smax = s.max() if s.size else 0.0
    keep = s > smax * 1e-12  # alpha = 0: minimum-norm least squares
    shrink = np.where(keep[None, :], s[None, :] / (s[None, :] ** 2 + alphas[:, None] + ~keep[None, :]), 0.0)
    w = np.einsum("pr,ar,rt->apt", vt.T, shrink, uty)  # (A, p, T)
    b = ym[None, :] - np.einsum("p,apt->at", fm, w)
    return w.reshape((len(alphas), f.shape[1], *tail)), b.reshape((len(alphas), *tail))


def ridge_cv(features: np.ndarray, targets: np.ndarray, mask: np.ndarray, folds: np.ndarray,
             alphas: np.ndarray) -> np.ndarray:
    """Blocked k-fold validation error ``(A, G)``: summed squared error of ``targets (N, G, K)``
    (masked by ``mask (G, K)``) on each held-out fold, summed over folds (fold ``-1``: always training)."""
    folds = np.asarray(folds)
    err = np.zeros((len(alphas), targets.shape[1]))
    for k in np.unique(folds[folds >= 0]):
        tr = folds != k
        w, b = ridge_path(features, targets, alphas, tr)
        pred = np.einsum("np,apgk->angk", features[~tr], w) + b[:, None]
        err += (((pred - targets[~tr][None]) * mask) ** 2).sum(axis=(1, 3))
    return err


def fit_ridge_per_group(features: np.ndarray, targets: np.ndarray, alpha: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Final fit with one ``alpha (G,)`` per group: ``weight (p, G, K)``, ``bias (G, K)``."""
    alpha = np.asarray(alpha, dtype=np.float64)
    uniq, inv = np.unique(alpha, return_inverse=True)
    w, b = ridge_path(features, targets, uniq)
    g = np.arange(targets.shape[1])
    return np.transpose(w[inv, :, g], (1, 0, 2)), b[inv, g]

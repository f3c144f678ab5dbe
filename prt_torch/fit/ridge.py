"""Ridge (Tikhonov) regression batched over output groups and a grid of regularisers.

Minimises ``||F_c W - Z_c||^2 + alpha ||W||^2`` (seed 000 section 4.1 with ``alpha`` in place of
``alpha^2``; ``F_c``, ``Z_c`` centred, so the intercept is not penalised). One thin SVD of the
shared design matrix serves every alpha and every group: ``W = V diag(s / (s^2 + alpha)) U^T Z_c``.
All float64. Numpy arrays in: numpy (LAPACK) on the CPU, the reference path; torch tensors in: the same
formulas on the tensors' device (:mod:`prt_torch.fit.device`), tensors out.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch

from prt_torch.errors import check
from prt_torch.fit.device import Array, like, permute, zeros
from prt_torch.shapes import check_shape


def ridge_path(features: Array, targets: Array, alphas: Any,
               sample_mask: Any = None) -> tuple[Array, Array]:
    """Fit every ``alpha``: ``features (N, p)``, ``targets (N, ...)`` -> ``weight (A, p, ...)``,
    ``bias (A, ...)``; only rows where ``sample_mask`` is true are used. A tensor ``features`` runs on its
    device (the other arguments are moved there)."""
    if isinstance(features, torch.Tensor):
        f = features.to(torch.float64)
        y = like(targets, f).to(torch.float64)
        alphas = torch.as_tensor(alphas if isinstance(alphas, torch.Tensor) else np.asarray(alphas, dtype=np.float64),
                                 dtype=torch.float64, device=f.device)
        sample_mask = None if sample_mask is None else like(sample_mask, f)
        svd, where, einsum = torch.linalg.svd, torch.where, torch.einsum
    else:
        f = np.asarray(features, dtype=np.float64)
        y = np.asarray(targets, dtype=np.float64)
        alphas = np.asarray(alphas, dtype=np.float64)
        svd, where, einsum = np.linalg.svd, np.where, np.einsum
    dims = check_shape(f, "N D", name="ridge: features")
    check_shape(y, "N ...", name="ridge: targets", dims=dims)
    check(bool((alphas >= 0).all()), "ridge: alphas must be >= 0")
    if sample_mask is not None:
        f, y = f[sample_mask], y[sample_mask]
    tail = tuple(y.shape[1:])
    y2 = y.reshape(y.shape[0], -1)
    fm, ym = f.mean(axis=0), y2.mean(axis=0)
    u, s, vt = svd(f - fm, full_matrices=False)
    uty = u.T @ (y2 - ym)  # (r, T)
    smax = s.max() if s.shape[0] else 0.0
    keep = s > smax * 1e-12  # alpha = 0: minimum-norm least squares
    shrink = where(keep[None, :], s[None, :] / (s[None, :] ** 2 + alphas[:, None] + ~keep[None, :]), 0.0)
    w = einsum("pr,ar,rt->apt", vt.T, shrink, uty)  # (A, p, T)
    b = ym[None, :] - einsum("p,apt->at", fm, w)
    return w.reshape((len(alphas), f.shape[1], *tail)), b.reshape((len(alphas), *tail))


def ridge_cv(features: Array, targets: Array, mask: Any, folds: np.ndarray, alphas: Any) -> Array:
    """Blocked k-fold validation error ``(A, G)``: summed squared error of ``targets (N, G, K)``
    (masked by ``mask (G, K)``) on each held-out fold, summed over folds (fold ``-1``: always training).
    ``folds (N,)`` is a host array; with tensor ``features`` the error is a tensor on their device."""
    folds = np.asarray(folds)
    targets, mask = like(targets, features), like(mask, features)
    err = zeros((len(alphas), targets.shape[1]), features)
    for k in np.unique(folds[folds >= 0]):
        tr = like(folds != k, features)
        w, b = ridge_path(features, targets, alphas, tr)
        pred = (torch.einsum if isinstance(w, torch.Tensor) else np.einsum)("np,apgk->angk", features[~tr], w) \
            + b[:, None]
        err += (((pred - targets[~tr][None]) * mask) ** 2).sum(axis=(1, 3))
    return err


def fit_ridge_per_group(features: Array, targets: Array, alpha: np.ndarray) -> tuple[Array, Array]:
    """Final fit with one ``alpha (G,)`` (a host array) per group: ``weight (p, G, K)``, ``bias (G, K)``."""
    alpha = np.asarray(alpha, dtype=np.float64)
    uniq, inv = np.unique(alpha, return_inverse=True)
    w, b = ridge_path(features, targets, uniq)
    g = like(np.arange(targets.shape[1]), w)
    inv = like(inv, w)
    return permute(w[inv, :, g], (1, 0, 2)), b[inv, g]

"""Error metrics between predicted and ground-truth SH signals and shaded radiance.

All inputs are numpy or torch arrays; results are Python floats or numpy arrays.

* :func:`vis_rel_err`: relative SH L2 error ``sqrt(sum |v - v*|^2 / sum |v*|^2)`` over all
  vertices and frames; by Parseval (orthonormal SH) it is the relative integrated squared error
  of the visibility functions over the sphere.
* :func:`transfer_error`: seed 000 section 6, ``E_j = int_{Omega_n} (T^g - T^s)^2 dw`` per vertex
  over the hemisphere about the normal (local ``+z`` for local-frame visibility), by quadrature.
* :func:`psnr`: ``10 log10(max(truth)^2 / MSE)`` over all entries (:func:`psnr_from_mse`, the one PSNR rule, also
  for pooled sums and images); :func:`rel_rmse`.
* :func:`evenly_spaced_indices`: the one rule picking ``n`` evenly spaced frames (rows) of ``n_total``.
* :func:`jitter`: mean absolute frame-to-frame change of the error, relative to the truth's scale.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from prt_torch.errors import check


def _np(a: Any) -> np.ndarray:
    if hasattr(a, "detach"):
        a = a.detach().cpu().numpy()
    return np.asarray(a, dtype=np.float64)


def _pair(pred: Any, truth: Any, name: str) -> tuple[np.ndarray, np.ndarray]:
    p, t = _np(pred), _np(truth)
    check(p.shape == t.shape, f"{name}: prediction {p.shape} and truth {t.shape} differ in shape")
    check(bool(np.isfinite(p).all()), f"{name}: prediction contains NaN or Inf")
    check(bool(np.isfinite(t).all()), f"{name}: truth contains NaN or Inf")
    return p, t


def vis_rel_err(pred: Any, truth: Any) -> float:
    """Relative SH L2 error over all of ``(F, V, C)``."""
    p, t = _pair(pred, truth, "vis_rel_err")
    den = float((t**2).sum())
    return float(np.sqrt(((p - t) ** 2).sum() / den)) if den > 0 else float(np.sqrt(((p - t) ** 2).sum()))


def per_frame_rel_err(pred: Any, truth: Any) -> np.ndarray:
    """``(F,)`` relative SH L2 error of each frame."""
    p, t = _pair(pred, truth, "per_frame_rel_err")
    ax = tuple(range(1, p.ndim))
    return np.sqrt(((p - t) ** 2).sum(ax) / np.maximum((t**2).sum(ax), 1e-30))


def hemisphere_gram(order: int, n_dirs: int = 4096) -> np.ndarray:
    """``(C, C)`` Gram matrix ``int_{z>0} y_i y_j dw`` by a fine midpoint rule in ``(cos, phi)``."""
    from prt_torch.sh.basis import sh_basis

    m = int(np.sqrt(n_dirs))
    mu = (np.arange(m) + 0.5) / m  # cos(theta) uniform on (0, 1): area element d(mu) d(phi)
    phi = (np.arange(2 * m) + 0.5) * np.pi / m
    mu_g, phi_g = np.meshgrid(mu, phi, indexing="ij")
    st = np.sqrt(1 - mu_g**2)
    dirs = np.stack([st * np.cos(phi_g), st * np.sin(phi_g), mu_g], -1).reshape(-1, 3)
    y = sh_basis(dirs, order)
    w = 2 * np.pi / dirs.shape[0]
    return (y.T @ y) * w


def transfer_error(pred: Any, truth: Any) -> np.ndarray:
    """Seed 000 section 6 per vertex and frame: ``(F, V)`` hemispherical integral of the squared
    difference of the SH functions (local frame, normal = ``+z``)."""
    p, t = _pair(pred, truth, "transfer_error")
    c = p.shape[-1]
    order = int(round(np.sqrt(c)))
    gram = hemisphere_gram(order)
    d = p - t
    return np.einsum("...i,ij,...j->...", d, gram, d)


def psnr_from_mse(mse: float, peak: float = 1.0) -> float:
    """``10 log10(peak^2 / mse)`` in dB (``peak`` at least 1e-15), ``inf`` for ``mse <= 0``: the one PSNR rule
    (:func:`psnr`, pooled radiance and image errors of :mod:`prt_torch.scoring`)."""
    if mse <= 0:
        return float("inf")
    return float(10 * np.log10(max(peak, 1e-15) ** 2 / mse))


def psnr(pred: Any, truth: Any) -> float:
    """``10 log10(max(truth)^2 / MSE)`` over all entries (dB)."""
    p, t = _pair(pred, truth, "psnr")
    return psnr_from_mse(float(((p - t) ** 2).mean()), abs(float(t.max())))


def evenly_spaced_indices(n_total: int, n_pick: int) -> np.ndarray:
    """``(n_pick,)`` int64 indices into ``n_total`` items, evenly spaced from the first to the last (rounded to the
    nearest; repeated when ``n_pick > n_total``)."""
    return np.linspace(0, n_total - 1, n_pick).round().astype(np.int64)


def rel_rmse(pred: Any, truth: Any) -> float:
    """``sqrt(mean (p - t)^2) / sqrt(mean t^2)``."""
    p, t = _pair(pred, truth, "rel_rmse")
    return float(np.sqrt(((p - t) ** 2).mean() / max(float((t**2).mean()), 1e-30)))


def jitter(pred: Any, truth: Any) -> float:
    """Temporal jitter: RMS over frames ``f`` of ``(p_{f+1} - p_f) - (t_{f+1} - t_f)`` relative
    to the RMS of the truth (frames are consecutive along axis 0; 0 for a perfect model)."""
    p, t = _pair(pred, truth, "jitter")
    if p.shape[0] < 2:
        return 0.0
    dd = np.diff(p, axis=0) - np.diff(t, axis=0)
    return float(np.sqrt((dd**2).mean() / max(float((t**2).mean()), 1e-30)))

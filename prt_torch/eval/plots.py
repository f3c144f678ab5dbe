"""Report figures (matplotlib, Agg), after the seeds' figures.

* :func:`plot_spectra`: PCA eigen-spectra of inputs and outputs (seed 000 Fig. 4);
* :func:`plot_error_vs_variance`: error vs retained output variance (seed 003 Fig. 5);
* :func:`plot_error_vs_alpha`: train and test error vs ridge alpha (seed 000 Fig. 3);
* :func:`plot_per_frame_error`: per-model error over novel-pose frames (seed 003 Fig. 7).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from prt_torch.io import atomic_path


def _fig():  # noqa: ANN202
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _save(fig, path: Path) -> Path:  # noqa: ANN001
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=110, bbox_inches="tight")
    _fig().close(fig)
    return path


def plot_spectra(input_explained: np.ndarray, output_explained: list[np.ndarray], input_k: int,
                 path: Path) -> Path:
    """Normalised eigenvalues of the pose PCA and of each cluster's output PCA (log scale)."""
    plt = _fig()
    fig, axes = plt.subplots(1, 2, figsize=(10, 3.6))
    e = input_explained / input_explained.sum()
    axes[0].semilogy(np.arange(1, len(e) + 1), e, "o-", ms=3)
    axes[0].axvline(input_k + 0.5, color="r", ls="--", label=f"kept {input_k}")
    axes[0].set(title="input (pose) PCA", xlabel="component", ylabel="fraction of variance",
                ylim=(max(float(e[e > 0].min()) if (e > 0).any() else 1e-12, 1e-10), 1.5))
    axes[0].legend()
    for ex in output_explained:
        ex = ex[ex > 0]
        if len(ex):
            axes[1].semilogy(np.arange(1, len(ex) + 1), ex / ex.sum(), "-", lw=0.8, alpha=0.6)
    axes[1].set(title="output PCA per cluster", xlabel="component", ylabel="fraction of variance", xlim=(0, 60))
    return _save(fig, path)


def plot_error_vs_variance(variances: list[float], errors: dict[str, list[float]], path: Path) -> Path:
    """Held-out visibility error of the models and the PCA floor vs retained output variance."""
    plt = _fig()
    fig, ax = plt.subplots(figsize=(5.5, 3.6))
    for name, err in errors.items():
        ax.plot(variances, err, "o-", label=name)
    ax.set(xlabel="retained output variance", ylabel="relative visibility error", title="error vs retained variance")
    ax.set_xscale("logit")
    ax.legend()
    return _save(fig, path)


def plot_error_vs_alpha(alphas: np.ndarray, train: np.ndarray, test: np.ndarray, chosen: float, path: Path) -> Path:
    """Train and held-out error of the ridge linear model vs alpha (alpha = 0 drawn at the left)."""
    plt = _fig()
    fig, ax = plt.subplots(figsize=(5.5, 3.6))
    a = np.where(alphas > 0, alphas, alphas[alphas > 0].min() / 10)
    ax.semilogx(a, train, "o-", label="train")
    ax.semilogx(a, test, "s-", label="held-out")
    ax.axvline(chosen, color="k", ls=":", label=f"CV median alpha {chosen:.3g}")
    ax.set(xlabel="alpha (leftmost point: unregularised)", ylabel="relative visibility error",
           title="linear model: error vs regularisation")
    ax.legend()
    return _save(fig, path)


def plot_per_frame_error(errors: dict[str, np.ndarray], path: Path) -> Path:
    """Per-frame relative visibility error of each model on the held-out frames."""
    plt = _fig()
    fig, ax = plt.subplots(figsize=(7, 3.6))
    for name, e in errors.items():
        ax.plot(np.arange(len(e)), e, label=f"{name} (mean {np.mean(e):.3f})")
    ax.set(xlabel="held-out frame", ylabel="relative visibility error", title="error on novel poses")
    ax.legend(fontsize=8)
    return _save(fig, path)

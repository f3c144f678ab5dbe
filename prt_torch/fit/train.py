"""Training: reduce, cross-validate and fit every model kind, write the run's model files.

``train(config)`` reads ``dataset.zarr`` (the ``train`` split, and ``heldout`` for the metrics
when present) and writes into the run directory::

    models/<kind>.pt     one VisibilityModel per kind (packed state dict + config)
    model.pt             the default kind (mlp when trained): a hard link, not a second copy
    model.json           metadata: conventions, order, V, A, kinds, dataset/character hash,
                         chosen alphas/neurons per cluster, CV scores, fit times
    metrics.json         visibility errors per kind on train and held-out frames
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch

from prt_torch.errors import PrtError, check
from prt_torch.eval.metrics import vis_rel_err
from prt_torch.fit.config import TrainConfig
from prt_torch.fit.data import DatasetInfo, SplitData, dataset_info, load_split
from prt_torch.fit.folds import blocked_folds
from prt_torch.fit.mlp import fit_mlp
from prt_torch.fit.ridge import fit_ridge_per_group, ridge_cv, ridge_path
from prt_torch.io import atomic_write_json
from prt_torch.models import (
    GlobalUnprojection,
    InputProjection,
    LinearRegressor,
    MLPRegressor,
    OutputUnprojection,
    QuadraticRegressor,
    VisibilityModel,
    link_default,
    save_model,
)
from prt_torch.models.regressors import quadratic_features
from prt_torch.reduce import PCA, ClusterPCA, GlobalOutputPCA


@dataclass
class Reduced:
    """Reductions fitted on the training split and the reduced training data."""

    inp: PCA
    out: ClusterPCA | GlobalOutputPCA
    x: np.ndarray  # (F, d)
    z: np.ndarray  # (F, G, Kmax)
    mask: np.ndarray  # (G, Kmax)
    folds: np.ndarray  # (F,)


@dataclass
class FitResult:
    """One fitted kind: the model and what model selection found."""

    kind: str
    model: VisibilityModel
    fit_s: float
    choice: dict[str, Any] = field(default_factory=dict)


def _log(progress: Any, msg: str) -> None:
    if progress is not None:
        progress.console.log(msg) if hasattr(progress, "console") else print(msg)


def reduce_training(train: SplitData, cluster: np.ndarray, cfg: TrainConfig) -> Reduced:
    """Input PCA of the poses, per-cluster output PCA of the visibility, blocked folds."""
    inp = PCA.fit(train.pose, variance=cfg.input_variance, whiten=cfg.whiten_inputs, name="pose features")
    if cfg.output_pca == "global":
        out: ClusterPCA | GlobalOutputPCA = GlobalOutputPCA.fit(train.visibility, variance=cfg.output_variance)
    else:
        out = ClusterPCA.fit(train.visibility, cluster, variance=cfg.output_variance)
    folds = blocked_folds(train.clip_id, train.frame_index, cfg.folds)
    return Reduced(inp=inp, out=out, x=inp.reduce(train.pose), z=out.reduce(train.visibility), mask=out.mask,
                   folds=folds)


def _ends(red: Reduced) -> tuple[InputProjection, OutputUnprojection | GlobalUnprojection]:
    proj = red.inp.components.T / red.inp.scale[None, :]
    inp = InputProjection(red.inp.mean, proj)
    if isinstance(red.out, GlobalOutputPCA):
        p = red.out.pca
        mean = np.repeat(p.mean[:, None], red.out.n_coeffs, axis=1).reshape(-1)  # (V, C) vertex-major
        return inp, GlobalUnprojection(p.components * p.scale[:, None], mean, red.out.n_vertices, red.out.n_coeffs)
    basis, gather, mean = red.out.padded_basis()
    return inp, OutputUnprojection(basis, gather, mean, red.out.n_vertices, red.out.n_coeffs)


def fit_ridge_kind(kind: str, red: Reduced, alphas: list[float], fixed_alpha: float | None = None) -> FitResult:
    """Linear or quadratic ridge; alpha per cluster by blocked CV unless ``fixed_alpha``."""
    t0 = time.perf_counter()
    x = torch.as_tensor(red.x)
    feats = (quadratic_features(x) if kind == "quadratic" else x).numpy()
    g = red.z.shape[1]
    choice: dict[str, Any] = {}
    if fixed_alpha is None:
        grid = np.asarray(alphas, dtype=np.float64)
        cv = ridge_cv(feats, red.z, red.mask, red.folds, grid)  # (A, G)
        best = grid[np.argmin(cv, axis=0)]
        choice = {"alphas": grid.tolist(), "cv_error": cv.sum(axis=1).tolist(), "alpha": best.tolist()}
    else:
        best = np.full(g, float(fixed_alpha))
        choice = {"alpha": best.tolist()}
    w, b = fit_ridge_per_group(feats, red.z, best)
    cls = QuadraticRegressor if kind == "quadratic" else LinearRegressor
    reg = cls(red.x.shape[1], g, red.z.shape[2])
    with torch.no_grad():
        reg.weight.copy_(torch.as_tensor(w * red.mask[None]))
        reg.bias.copy_(torch.as_tensor(b * red.mask))
    inp, out = _ends(red)
    model = VisibilityModel(kind, inp, reg, out).float().eval()
    return FitResult(kind, model, time.perf_counter() - t0, choice)


def fit_mlp_kind(red: Reduced, cfg: TrainConfig, progress: Any = None) -> FitResult:
    """Per-cluster tanh MLP: (neurons, alpha) per cluster by blocked CV, then one final L-BFGS."""
    t0 = time.perf_counter()
    x = torch.as_tensor(red.x)
    z = torch.as_tensor(red.z)
    om = torch.as_tensor(red.mask)
    g = z.shape[1]
    folds = np.unique(red.folds)
    alphas = np.asarray(cfg.mlp_alphas, dtype=np.float64)
    neurons = sorted(set(cfg.neurons))
    task = progress.add_task("mlp", total=None) if progress is not None else None

    def report(stage: str) -> Any:
        def cb(it: int, loss: float) -> None:
            if progress is not None:
                progress.update(task, description=f"mlp {stage}: iter {it} objective {loss:.4g}")
        return cb

    # L-BFGS starts from the ridge-linear solution (alpha per cluster by the same blocked CV)
    lin_grid = np.asarray(cfg.alphas, dtype=np.float64)
    lin_alpha = lin_grid[np.argmin(ridge_cv(red.x, red.z, red.mask, red.folds, lin_grid), axis=0)]

    def linear_init(train_mask: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
        uniq, inv = np.unique(lin_alpha, return_inverse=True)
        w, b = ridge_path(red.x, red.z, uniq, train_mask)  # (U, d, G, K), (U, G, K)
        gi = np.arange(g)
        return np.transpose(w[inv, :, gi], (0, 1, 2)) * red.mask[:, None, :], b[inv, gi] * red.mask

    cv = np.zeros((len(neurons), len(alphas), g))
    if len(neurons) * len(alphas) > 1:
        n_s = len(folds) * len(alphas)
        fold_of = np.repeat(folds, len(alphas))
        alpha_of = np.tile(alphas, len(folds))
        weight = torch.as_tensor((red.folds[None, :] != fold_of[:, None]).astype(np.float64))
        alpha_t = torch.as_tensor(np.repeat(alpha_of[:, None], g, axis=1))
        inits = {f: linear_init(red.folds != f) for f in folds}
        init = (torch.as_tensor(np.stack([inits[f][0] for f in fold_of])),
                torch.as_tensor(np.stack([inits[f][1] for f in fold_of])))
        for i, n in enumerate(neurons):
            params, _, _ = fit_mlp(x, z, om, weight, alpha_t, torch.ones(n_s, g, n), max_iter=cfg.cv_iter,
                                   seed=cfg.seed, history_size=cfg.history_size, progress=report(f"CV N={n}"),
                                   init_linear=init)
            with torch.no_grad():
                from prt_torch.fit.mlp import mlp_forward

                pred = mlp_forward(x.double(), params)  # (S, G, F, K)
            err = ((pred - z.permute(1, 0, 2).unsqueeze(0)) * om[None, :, None, :]).pow(2).sum(-1)  # (S, G, F)
            held = torch.as_tensor((red.folds[None, :] == fold_of[:, None]).astype(np.float64))
            e = (err * held[:, None, :]).sum(-1).numpy()  # (S, G)
            cv[i] = e.reshape(len(folds), len(alphas), g).sum(0)
        flat = cv.reshape(-1, g)
        best = np.argmin(flat, axis=0)
        best_n = np.asarray(neurons)[best // len(alphas)]
        best_a = alphas[best % len(alphas)]
    else:
        best_n = np.full(g, neurons[0])
        best_a = np.full(g, alphas[0])
    nmax = int(best_n.max())
    nmask = torch.as_tensor((np.arange(nmax)[None, :] < best_n[:, None]).astype(np.float64)).unsqueeze(0)
    w0, b0 = linear_init(None)
    params, loss, iters = fit_mlp(x, z, om, torch.ones(1, x.shape[0]), torch.as_tensor(best_a)[None], nmask,
                                  max_iter=cfg.max_iter, seed=cfg.seed, history_size=cfg.history_size,
                                  progress=report("final"),
                                  init_linear=(torch.as_tensor(w0)[None], torch.as_tensor(b0)[None]))
    if progress is not None:
        progress.remove_task(task)
    reg = MLPRegressor(red.x.shape[1], g, red.z.shape[2], nmax)
    with torch.no_grad():
        reg.hidden_weight.copy_(params.D[0])
        reg.hidden_bias.copy_(params.d0[0])
        reg.out_weight.copy_(params.C[0])
        reg.out_bias.copy_(params.c0[0])
    inp, out = _ends(red)
    model = VisibilityModel("mlp", inp, reg, out).float().eval()
    choice = {"neurons_grid": neurons, "alphas": alphas.tolist(), "cv_error": cv.sum(axis=2).tolist(),
              "neurons": best_n.tolist(), "alpha": best_a.tolist(), "objective": loss, "iterations": iters}
    return FitResult("mlp", model, time.perf_counter() - t0, choice)


def fit_kinds(red: Reduced, cfg: TrainConfig, progress: Any = None) -> dict[str, FitResult]:
    """Fit every kind of ``cfg.kinds``."""
    out: dict[str, FitResult] = {}
    for kind in cfg.kinds:
        _log(progress, f"fitting {kind} ({red.x.shape[0]} frames, {red.x.shape[1]} inputs, "
                       f"{red.z.shape[1]} clusters x {red.z.shape[2]} outputs)")
        if kind == "mlp":
            out[kind] = fit_mlp_kind(red, cfg, progress)
        else:
            out[kind] = fit_ridge_kind(kind, red, cfg.alphas)
        _log(progress, f"{kind}: fitted in {out[kind].fit_s:.2f} s")
    return out


def predict(model: VisibilityModel, pose: np.ndarray) -> np.ndarray:
    """``(F, A)`` -> ``(F, V, C)`` numpy float32."""
    return model.predict(pose).numpy()


def _metadata(info: DatasetInfo, cfg: TrainConfig, red: Reduced, fits: dict[str, FitResult], default: str,
              train: SplitData) -> dict[str, Any]:
    return {
        "format": "prt_torch.run/1",
        "conventions": info.attrs.get("conventions", "see docs/DESIGN.md: real SH (R&H 2001, no Condon-Shortley), "
                                      "local vertex frame rows (t, b, n), visibility 0 below the horizon"),
        "order": info.order,
        "n_coeffs": info.n_coeffs,
        "n_vertices": info.n_vertices,
        "n_features": info.n_features,
        "reduced_inputs": red.inp.n_components,
        "input_retained": red.inp.retained,
        "output_pca": cfg.output_pca,
        "output_dims": red.out.dims.tolist(),
        "output_width": red.out.width,
        "n_clusters": red.out.n_groups,
        "kinds": list(fits),
        "default_kind": default,
        "dataset": str(info.path),
        "character_hash": info.character_hash,
        "train_clips": train.clips,
        "train_frames": train.n_frames,
        "train_config": cfg.model_dump(),
        "fit": {k: {"fit_s": r.fit_s, **r.choice} for k, r in fits.items()},
    }


def train_dataset(dataset: str | Path, run_dir: str | Path, cfg: TrainConfig | None = None,
                  progress: Any = None) -> dict[str, Any]:
    """Train every kind on ``dataset`` and write the run files into ``run_dir``; returns metrics."""
    cfg = cfg or TrainConfig()
    run_dir = Path(run_dir)
    info = dataset_info(dataset)
    torch.manual_seed(cfg.seed)
    threads = torch.get_num_threads()
    if cfg.threads:
        # the L-BFGS two-loop recursion is many tiny vector ops: thread sync dominates (10x on 2 busy cores)
        torch.set_num_threads(cfg.threads)
    try:
        if cfg.threads:
            from threadpoolctl import threadpool_limits

            with threadpool_limits(limits=cfg.threads):
                return _train(dataset, run_dir, cfg, info, progress)
        return _train(dataset, run_dir, cfg, info, progress)
    finally:
        torch.set_num_threads(threads)


def _train(dataset: str | Path, run_dir: Path, cfg: TrainConfig, info: DatasetInfo, progress: Any) -> dict[str, Any]:
    train = load_split(dataset, "train")
    check(train.n_frames >= 2 * cfg.folds, f"{dataset}: only {train.n_frames} training frames for {cfg.folds} folds")
    red = reduce_training(train, info.cluster, cfg)
    _log(progress, f"input PCA: {info.n_features} -> {red.inp.n_components} dims ({red.inp.retained:.3f} variance); "
                   f"output PCA: {red.out.n_groups} clusters, dims {red.out.dims.min()}..{red.out.width}")
    fits = fit_kinds(red, cfg, progress)
    (run_dir / "models").mkdir(parents=True, exist_ok=True)
    for kind, r in fits.items():
        save_model(r.model, run_dir / "models" / f"{kind}.pt")
    default = cfg.default_kind if cfg.default_kind in fits else next(iter(fits))
    link_default(run_dir, default)
    meta = _metadata(info, cfg, red, fits, default, train)
    metrics: dict[str, Any] = {"models": {}}
    splits = {"train": train}
    if "heldout" in info.splits:
        try:
            splits["heldout"] = load_split(dataset, "heldout", max_frames=cfg.eval_frames)
        except PrtError:
            pass
    for kind, r in fits.items():
        metrics["models"][kind] = {"fit_s": r.fit_s}
        for name, sp in splits.items():
            metrics["models"][kind][name] = {"vis_rel_err": vis_rel_err(predict(r.model, sp.pose), sp.visibility)}
    for name, sp in splits.items():
        metrics.setdefault("pca_floor", {})[name] = vis_rel_err(red.out.expand(red.out.reduce(sp.visibility)),
                                                               sp.visibility)
    atomic_write_json(run_dir / "model.json", meta)
    atomic_write_json(run_dir / "metrics.json", metrics)
    return metrics


def train(config: Any, progress: Any = None) -> Path:
    """Train from a :class:`prt_torch.config.RunConfig`; returns the run directory."""
    run_dir = Path(config.out_dir)
    dataset = config.resolve(config.train.dataset) if config.train.dataset else run_dir / "dataset.zarr"
    train_dataset(dataset, run_dir, config.train, progress)
    return run_dir

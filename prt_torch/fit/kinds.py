"""The fitters of every visibility kind on the training split: the input and output reductions
(:func:`reduce_training` -> :class:`Reduced`), the ridge kinds (linear, quadratic: :func:`fit_ridge_kind`) and the
MLP (:func:`fit_mlp_kind`), each model selected by blocked cross-validation (:func:`fit_kinds`). The run's training
stage (:mod:`prt_torch.fit.train`) and the learned transfer (:mod:`prt_torch.transfer.fit`) both use them.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import torch

from prt_torch.bake.store import BakedDataset, SplitData
from prt_torch.fit.config import TrainConfig
from prt_torch.fit.device import Array, concat, fit_device, host, like, permute, stack, zeros
from prt_torch.fit.folds import blocked_folds
from prt_torch.fit.inputs import JointInputs, joint_inputs
from prt_torch.fit.mlp import fit_mlp
from prt_torch.fit.ridge import fit_ridge_per_group, ridge_cv, ridge_path
from prt_torch.models import (
    GlobalUnprojection,
    InputProjection,
    LinearRegressor,
    MLPRegressor,
    OutputUnprojection,
    QuadraticRegressor,
    VisibilityModel,
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
    sel: JointInputs | None = None  # per-cluster joint inputs (linear and mlp) when input_selection = joints
    xs: np.ndarray | None = None  # (F, d') the selected standardised inputs

    def inputs(self, kind: str) -> tuple[np.ndarray, np.ndarray | None]:
        """The training inputs of ``kind`` and its per-cluster input mask ``(G, d)`` (None: all)."""
        if self.sel is not None and kind in SELECTED_KINDS:
            return self.xs, self.sel.mask
        return self.x, None


@dataclass
class FitResult:
    """One fitted kind: the model and what model selection found."""

    kind: str
    model: VisibilityModel
    fit_s: float
    choice: dict[str, Any] = field(default_factory=dict)


def log_progress(progress: Any, msg: str) -> None:
    if progress is not None:
        progress.console.log(msg) if hasattr(progress, "console") else print(msg)


SELECTED_KINDS = ("linear", "mlp")  # quadratic keeps the PCA inputs (its feature count is quadratic in d)


def reduce_training(train: SplitData, cluster: np.ndarray, cfg: TrainConfig,
                    skinning: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None,
                    train_only: np.ndarray | None = None) -> Reduced:
    """Input PCA of the poses, per-cluster output PCA of the visibility, blocked folds; with
    ``skinning = (parents, joints, weights)`` also the per-cluster joint inputs. ``train_only (F,)``: frames
    never validated on in CV (``cv_validate: clips``: the random poses)."""
    inp = PCA.fit(train.pose, variance=cfg.input_variance, whiten=cfg.whiten_inputs, name="pose features",
                  max_components=cfg.input_max_components)
    if cfg.output_pca == "global":
        out: ClusterPCA | GlobalOutputPCA = GlobalOutputPCA.fit(train.visibility, variance=cfg.output_variance)
    else:
        out = ClusterPCA.fit(train.visibility, cluster, variance=cfg.output_variance,
                             max_components=cfg.output_max_components)
    folds = blocked_folds(train.clip_id, train.frame_index, cfg.folds, train_only)
    sel = xs = None
    if skinning is not None:
        labels = np.unique(cluster, return_inverse=True)[1] if cfg.output_pca == "cluster" else np.zeros_like(cluster)
        sel = joint_inputs(train.pose, *skinning, labels, cfg.selection_weight)
        xs = sel.reduce(train.pose)
    return Reduced(inp=inp, out=out, x=inp.reduce(train.pose), z=out.reduce(train.visibility), mask=out.mask,
                   folds=folds, sel=sel, xs=xs)


def _ends(red: Reduced, kind: str = "quadratic") -> tuple[InputProjection, OutputUnprojection | GlobalUnprojection]:
    if red.sel is not None and kind in SELECTED_KINDS:
        inp = InputProjection(red.sel.mean, red.sel.proj)
    else:
        inp = InputProjection(red.inp.mean, red.inp.components.T / red.inp.scale[None, :])
    if isinstance(red.out, GlobalOutputPCA):
        p = red.out.pca
        mean = np.repeat(p.mean[:, None], red.out.n_coeffs, axis=1).reshape(-1)  # (V, C) vertex-major
        return inp, GlobalUnprojection(p.components * p.scale[:, None], mean, red.out.n_vertices, red.out.n_coeffs)
    basis, gather, mean = red.out.padded_basis()
    return inp, OutputUnprojection(basis, gather, mean, red.out.n_vertices, red.out.n_coeffs)


def _masked_ridge_cv(x: Array, z: Array, mask: Array, folds: np.ndarray, grid: np.ndarray,
                     in_mask: np.ndarray | None) -> Array:
    """``ridge_cv`` with cluster ``g`` restricted to the inputs ``in_mask[g]`` -> ``(A, G)`` (numpy arrays, or
    tensors on ``x``'s device)."""
    if in_mask is None:
        return ridge_cv(x, z, mask, folds, grid)
    in_mask = like(in_mask, x)
    return concat([ridge_cv(x * in_mask[g], z[:, g:g + 1], mask[g:g + 1], folds, grid)
                   for g in range(z.shape[1])], axis=1)


def _masked_ridge(x: Array, z: Array, alpha: np.ndarray, in_mask: np.ndarray | None,
                  sample_mask: Array | None = None) -> tuple[Array, Array]:
    """Ridge with one ``alpha (G,)`` per cluster (each on its own inputs): ``weight (d, G, K)``, ``bias (G, K)``.
    A zeroed input column gets a zero weight (minimum-norm solution). Numpy arrays, or tensors on ``x``'s device."""
    g = z.shape[1]
    if in_mask is None:
        in_mask = np.ones((g, x.shape[1]), dtype=bool)
    in_mask = like(in_mask, x)
    w = zeros((x.shape[1], g, z.shape[2]), x)
    b = zeros((g, z.shape[2]), x)
    for i in range(g):
        wi, bi = ridge_path(x * in_mask[i], z[:, i], np.asarray([alpha[i]]), sample_mask)
        w[:, i], b[i] = wi[0] * in_mask[i][:, None], bi[0]
    return w, b


def fit_ridge_kind(kind: str, red: Reduced, alphas: list[float], fixed_alpha: float | None = None,
                   device: torch.device | None = None) -> FitResult:
    """Linear or quadratic ridge; alpha per cluster by blocked CV unless ``fixed_alpha``. ``device``: None = the
    numpy reference path on the CPU, else the solves run there (data moved once); the model is on the CPU."""
    t0 = time.perf_counter()
    xin, in_mask = red.inputs(kind)
    x = torch.as_tensor(xin)
    if device is None:
        feats: Array = (quadratic_features(x) if kind == "quadratic" else x).numpy()
        z, zmask = red.z, red.mask
    else:
        x = x.to(device)
        feats = quadratic_features(x) if kind == "quadratic" else x
        z, zmask = like(red.z, x), like(red.mask, x)
    g = red.z.shape[1]
    choice: dict[str, Any] = {}
    if fixed_alpha is None:
        grid = np.asarray(alphas, dtype=np.float64)
        cv = host(_masked_ridge_cv(feats, z, zmask, red.folds, grid, in_mask))  # (A, G)
        best = grid[np.argmin(cv, axis=0)]
        choice = {"alphas": grid.tolist(), "cv_error": cv.sum(axis=1).tolist(), "alpha": best.tolist()}
    else:
        best = np.full(g, float(fixed_alpha))
        choice = {"alpha": best.tolist()}
    if in_mask is None:
        w, b = fit_ridge_per_group(feats, z, best)
    else:
        w, b = _masked_ridge(feats, z, best, in_mask)
        choice["inputs_per_cluster"] = in_mask.sum(1).tolist()
    w, b = host(w), host(b)
    cls = QuadraticRegressor if kind == "quadratic" else LinearRegressor
    reg = cls(xin.shape[1], g, red.z.shape[2])
    with torch.no_grad():
        reg.weight.copy_(torch.as_tensor(w * red.mask[None]))
        reg.bias.copy_(torch.as_tensor(b * red.mask))
    inp, out = _ends(red, kind)
    model = VisibilityModel(kind, inp, reg, out).float().eval()
    return FitResult(kind, model, time.perf_counter() - t0, choice)


def fit_mlp_kind(red: Reduced, cfg: TrainConfig, progress: Any = None, device: torch.device | None = None) -> FitResult:
    """Per-cluster tanh MLP: (neurons, alpha) per cluster by blocked CV, then one final L-BFGS. ``device``: None =
    the reference path on the CPU, else the ridge starts, the L-BFGS fits and the CV errors run there (the
    training data moved once); the model is on the CPU."""
    t0 = time.perf_counter()
    dev = torch.device("cpu") if device is None else device
    xin, in_mask = red.inputs("mlp")
    x = torch.as_tensor(xin).to(dev)
    im = None if in_mask is None else torch.as_tensor(in_mask).to(dev)
    z = torch.as_tensor(red.z).to(dev)
    om = torch.as_tensor(red.mask).to(dev)
    # the ridge starts' data: numpy on the reference path, the tensors above otherwise
    rx, rz, rmask = (xin, red.z, red.mask) if device is None else (x, z, om)
    g = z.shape[1]
    folds = np.unique(red.folds[red.folds >= 0])  # fold -1: always training (cv_validate: clips)
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
    lin_alpha = lin_grid[np.argmin(host(_masked_ridge_cv(rx, rz, rmask, red.folds, lin_grid, in_mask)), axis=0)]

    def linear_init(train_mask: np.ndarray | None) -> tuple[Array, Array]:
        tm = None if train_mask is None else like(train_mask, rx)
        if in_mask is not None:
            w, b = _masked_ridge(rx, rz, lin_alpha, in_mask, tm)  # (d, G, K), (G, K)
            return permute(w, (1, 0, 2)) * rmask[:, None, :], b * rmask
        uniq, inv = np.unique(lin_alpha, return_inverse=True)
        w, b = ridge_path(rx, rz, uniq, tm)  # (U, d, G, K), (U, G, K)
        inv, gi = like(inv, w), like(np.arange(g), w)
        return w[inv, :, gi] * rmask[:, None, :], b[inv, gi] * rmask

    cv = np.zeros((len(neurons), len(alphas), g))
    if len(neurons) * len(alphas) > 1:
        n_s = len(folds) * len(alphas)
        fold_of = np.repeat(folds, len(alphas))
        alpha_of = np.tile(alphas, len(folds))
        weight = torch.as_tensor((red.folds[None, :] != fold_of[:, None]).astype(np.float64)).to(dev)
        alpha_t = torch.as_tensor(np.repeat(alpha_of[:, None], g, axis=1)).to(dev)
        inits = {f: linear_init(red.folds != f) for f in folds}
        init = (torch.as_tensor(stack([inits[f][0] for f in fold_of])).to(dev),
                torch.as_tensor(stack([inits[f][1] for f in fold_of])).to(dev))
        held = torch.as_tensor((red.folds[None, :] == fold_of[:, None]).astype(np.float64)).to(dev)
        for i, n in enumerate(neurons):
            params, _, _ = fit_mlp(x, z, om, weight, alpha_t, torch.ones(n_s, g, n, device=dev),
                                   max_iter=cfg.cv_iter, seed=cfg.seed, history_size=cfg.history_size,
                                   progress=report(f"CV N={n}"), init_linear=init, input_mask=im, device=device)
            with torch.no_grad():
                from prt_torch.fit.mlp import mlp_forward

                pred = mlp_forward(x.double(), params.to(dev))  # (S, G, F, K)
            err = ((pred - z.permute(1, 0, 2).unsqueeze(0)) * om[None, :, None, :]).pow(2).sum(-1)  # (S, G, F)
            e = host((err * held[:, None, :]).sum(-1))  # (S, G)
            cv[i] = e.reshape(len(folds), len(alphas), g).sum(0)
        flat = cv.reshape(-1, g)
        best = np.argmin(flat, axis=0)
        best_n = np.asarray(neurons)[best // len(alphas)]
        best_a = alphas[best % len(alphas)]
    else:
        best_n = np.full(g, neurons[0])
        best_a = np.full(g, alphas[0])
    nmax = int(best_n.max())
    nmask = torch.as_tensor((np.arange(nmax)[None, :] < best_n[:, None]).astype(np.float64)).unsqueeze(0).to(dev)
    w0, b0 = linear_init(None)
    params, loss, iters = fit_mlp(x, z, om, torch.ones(1, x.shape[0], device=dev),
                                  torch.as_tensor(best_a)[None].to(dev), nmask,
                                  max_iter=cfg.max_iter, seed=cfg.seed, history_size=cfg.history_size,
                                  progress=report("final"),
                                  init_linear=(torch.as_tensor(w0)[None].to(dev), torch.as_tensor(b0)[None].to(dev)),
                                  input_mask=im, device=device)
    if progress is not None:
        progress.remove_task(task)
    reg = MLPRegressor(xin.shape[1], g, red.z.shape[2], nmax)
    with torch.no_grad():
        reg.hidden_weight.copy_(params.D[0])
        reg.hidden_bias.copy_(params.d0[0])
        reg.out_weight.copy_(params.C[0])
        reg.out_bias.copy_(params.c0[0])
    inp, out = _ends(red, "mlp")
    model = VisibilityModel("mlp", inp, reg, out).float().eval()
    choice = {"neurons_grid": neurons, "alphas": alphas.tolist(), "cv_error": cv.sum(axis=2).tolist(),
              "neurons": best_n.tolist(), "alpha": best_a.tolist(), "objective": loss, "iterations": iters}
    return FitResult("mlp", model, time.perf_counter() - t0, choice)


def fit_kinds(red: Reduced, cfg: TrainConfig, progress: Any = None) -> dict[str, FitResult]:
    """Fit every kind of ``cfg.kinds`` on ``cfg.device`` (:func:`prt_torch.fit.device.fit_device`)."""
    out: dict[str, FitResult] = {}
    device = fit_device(cfg.device)
    for kind in cfg.kinds:
        log_progress(progress, f"fitting {kind} ({red.x.shape[0]} frames, {red.inputs(kind)[0].shape[1]} inputs, "
                       f"{red.z.shape[1]} clusters x {red.z.shape[2]} outputs) on {device or 'cpu'}")
        if kind == "mlp":
            out[kind] = fit_mlp_kind(red, cfg, progress, device)
        else:
            out[kind] = fit_ridge_kind(kind, red, cfg.alphas, device=device)
        log_progress(progress, f"{kind}: fitted in {out[kind].fit_s:.2f} s")
    return out


def cv_train_only(ds: BakedDataset, train: SplitData, cfg: TrainConfig) -> np.ndarray | None:
    """``(F,)`` training frames never validated on (``cv_validate: clips``: the random poses), else None."""
    if cfg.cv_validate != "clips":
        return None
    from prt_torch.bake.plan import RANDOM_CLIP

    random_ids = [i for i, n in enumerate(ds.clip_names) if n == RANDOM_CLIP]
    return np.isin(train.clip_id, random_ids)

"""Learned diffuse transfer (seed 000): the visibility regressors fitted to the baked transfer vectors.

Targets: the bake's world-frame diffuse transfer ``transfer (F, V, C6)`` (``int V(w) max(n.w, 0)/pi y(w) dw`` plus
``bake.bounces`` interreflection bounces; shading ``albedo * (L . t)``,
:func:`prt_torch.shade.diffuse.shade_diffuse_prt`), and the ``subsurface (F, V, C6)`` exit-radiance transfer when
the store has it. Each array gets the same pipeline as the visibility (:mod:`prt_torch.fit.train`, its building blocks
reused, not copied):

* input PCA of the pose features, ``input_components`` kept (seed 000 sec. 5: 8 of 53 angles), else
  ``input_variance``;
* output PCA ``global`` (seed 000 sec. 5, :class:`prt_torch.reduce.GlobalOutputPCA`: one basis of
  ``output_components`` vertex vectors shared by every SH coefficient, Table 1's PCA(8, 22)), or per ``cluster``
  (:class:`prt_torch.reduce.ClusterPCA` over the bake's vertex clusters, ``output_components`` per cluster);
* the regressors of ``train.transfer.kinds`` (ridge ``linear`` = seed 000 sec. 4.1 Tikhonov, ``quadratic``,
  per-cluster tanh ``mlp`` with L-BFGS), hyper-parameters by the same blocked CV and grids as the visibility
  (``train.alphas`` ...), or one fixed ``alpha``.

Files (run directory, names from :class:`prt_torch.rundir.RunDir`): ``models/<array>_<kind>.pt`` (a
:class:`prt_torch.models.VisibilityModel`: pose ``(B, A)`` -> ``(B, V, C6)``, world frame) and ``transfer.json``
(settings, reductions, CV choices, errors, sha256 of every model file), written by ``prt train`` inside its
unit before ``model.json``. ``transfer_rel_err`` = ``sqrt(sum |t_pred - t|^2 / sum |t|^2)`` over frames, vertices
and coefficients: the relative L2 of the transfer functions over the sphere (orthonormal SH; the world-frame
transfer has no single hemisphere, so this is the full-sphere form of seed 000 sec. 6's error).
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

from prt_torch.bake.store import BakedDataset, SplitData
from prt_torch.errors import MissingArtifact, check
from prt_torch.fit.config import TrainConfig, TransferConfig
from prt_torch.fit.folds import blocked_folds
from prt_torch.fit.kinds import FitResult, Reduced, cv_train_only, fit_kinds, fit_ridge_kind, log_progress
from prt_torch.fit.stages import FitHook
from prt_torch.io import atomic_write_json
from prt_torch.metrics import vis_rel_err
from prt_torch.models import save_model
from prt_torch.reduce import PCA, ClusterPCA, GlobalOutputPCA
from prt_torch.rundir import RunDir

#: the per-frame transfer arrays of a store that are learned, in this order
ARRAYS: tuple[str, ...] = ("transfer", "subsurface")
FORMAT = "prt_torch.learned_transfer/1"


def check_target(y: Any, n_frames: int, name: str = "transfer") -> np.ndarray:
    """Validate a transfer target ``(F, V, C6)`` (``C6`` a square, finite, ``F == n_frames``) -> float64."""
    y = np.asarray(y, dtype=np.float64)
    check(y.ndim == 3 and y.shape[0] == n_frames and y.shape[1] > 0,
          f"{name}: expected a ({n_frames}, V, C) array, got shape {y.shape}")
    c = y.shape[2]
    check(c > 0 and int(round(c**0.5)) ** 2 == c, f"{name}: last axis must be order**2 SH coefficients, got {c}")
    check(bool(np.isfinite(y).all()), f"{name}: contains NaN or Inf")
    return y


def _truncate(p: PCA, k: int | None) -> PCA:
    """``p`` keeping its first ``k`` components (``None``: unchanged)."""
    if k is None or k >= p.n_components:
        return p
    total = float(p.explained.sum())
    return dataclasses.replace(p, components=p.components[:k], scale=p.scale[:k],
                               retained=float(p.explained[:k].sum() / total) if total > 0 else 1.0)


def output_reduction(y: np.ndarray, cluster: np.ndarray, tcfg: TransferConfig) -> ClusterPCA | GlobalOutputPCA:
    """The output PCA of ``y (F, V, C6)``: ``global`` or per ``cluster`` (labels ``cluster (V,)``), keeping
    ``output_components`` (per cluster), else ``output_variance``."""
    k = tcfg.output_components
    var = 1.0 if k is not None else tcfg.output_variance  # a fixed count: fit the spectrum, then truncate
    if tcfg.output_pca == "global":
        out = GlobalOutputPCA.fit(y, variance=var)
        return dataclasses.replace(out, pca=_truncate(out.pca, k), variance=float(var))
    cp = ClusterPCA.fit(y, cluster, variance=var)
    return dataclasses.replace(cp, pcas=[_truncate(p, k) for p in cp.pcas])


def reduce_transfer(train: SplitData, target: np.ndarray, cluster: np.ndarray, tcfg: TransferConfig,
                    cfg: TrainConfig, train_only: np.ndarray | None = None) -> Reduced:
    """Input PCA of ``train.pose``, output PCA of ``target (F, V, C6)`` (the training split's transfer), blocked
    folds (``cfg.folds``): the :class:`prt_torch.fit.kinds.Reduced` the visibility fitters take."""
    y = check_target(target, train.n_frames)
    check(train.n_frames >= 2 * cfg.folds, f"only {train.n_frames} training frames for {cfg.folds} folds")
    inp = PCA.fit(train.pose, variance=tcfg.input_variance, n_components=tcfg.input_components,
                  whiten=cfg.whiten_inputs, name="pose features")
    out = output_reduction(y, cluster, tcfg)
    folds = blocked_folds(train.clip_id, train.frame_index, cfg.folds, train_only)
    return Reduced(inp=inp, out=out, x=inp.reduce(train.pose), z=out.reduce(y), mask=out.mask, folds=folds)


def fit_transfer(red: Reduced, tcfg: TransferConfig, cfg: TrainConfig, progress: Any = None) -> dict[str, FitResult]:
    """Fit every kind of ``tcfg.kinds`` on ``red`` with ``cfg``'s grids (``tcfg.alpha``: fixed ridge alpha)."""
    sub = cfg.model_copy(update={"kinds": list(tcfg.kinds), "input_selection": "pca"})
    if tcfg.alpha is None:
        return fit_kinds(red, sub, progress)
    out = {}
    ridge = [k for k in tcfg.kinds if k != "mlp"]
    for kind in ridge:
        out[kind] = fit_ridge_kind(kind, red, cfg.alphas, fixed_alpha=tcfg.alpha)
    if "mlp" in tcfg.kinds:
        out.update(fit_kinds(red, sub.model_copy(update={"kinds": ["mlp"]}), progress))
    return {k: out[k] for k in tcfg.kinds}


def transfer_rel_err(pred: Any, truth: Any) -> float:
    """``sqrt(sum |pred - truth|^2 / sum |truth|^2)`` (full-sphere relative L2 of SH functions)."""
    return vis_rel_err(pred, truth)


def _reduction_meta(red: Reduced) -> dict[str, Any]:
    out = red.out
    pcas = [out.pca] if isinstance(out, GlobalOutputPCA) else out.pcas
    retained = float(np.average([p.retained for p in pcas], weights=[max(float(p.explained.sum()), 1e-30)
                                                                      for p in pcas]))
    return {"reduced_inputs": red.inp.n_components, "input_retained": red.inp.retained,
            "output_dims": out.dims.tolist(), "output_width": out.width, "n_clusters": out.n_groups,
            "output_retained": retained, "output_basis_floats": out.compact_floats()}


def learned_arrays(ds: BakedDataset) -> list[str]:
    """The transfer arrays the store holds (of :data:`ARRAYS`)."""
    return [a for a in ARRAYS if a in ds]


def train_transfer(ds: BakedDataset, run: RunDir, cfg: TrainConfig, progress: Any = None) -> dict[str, Any] | None:
    """The ``prt train`` step of ``train.transfer``: fit, save ``models/<array>_<kind>.pt``, write ``transfer.json``
    (the models' sha256 in ``files``); returns the errors for ``metrics.json``. Without ``train.transfer`` a
    stale ``transfer.json`` is removed (its models no longer belong to this training) and None returned."""
    tcfg = cfg.transfer
    if tcfg is None:
        run.transfer_json.unlink(missing_ok=True)
        return None
    arrays = learned_arrays(ds)
    check(bool(arrays), f"{ds.path}: train.transfer needs a dataset baked with `bake.transfer: true` "
                        f"(it has no transfer array)")
    run.transfer_json.unlink(missing_ok=True)  # the old record goes first: a kill below leaves no stale claim
    train = ds.split("train", extra=tuple(arrays))
    held = None
    if "heldout" in ds.splits:
        try:
            held = ds.split("heldout", extra=tuple(arrays), max_frames=cfg.eval_frames)
        except MissingArtifact:  # no held-out frame baked yet
            held = None
    train_only = cv_train_only(ds, train, cfg)
    meta: dict[str, Any] = {"format": FORMAT, "config": tcfg.model_dump(mode="json"), "arrays": {},
                            "default_kind": "mlp" if "mlp" in tcfg.kinds else tcfg.kinds[0],
                            "kinds": list(tcfg.kinds), "n_features": ds.n_features, "n_vertices": ds.n_vertices,
                            "bake": {k: (ds.attrs.get("bake") or {}).get(k) for k in
                                     ("transfer_order", "bounces", "albedo", "subsurface")},
                            "error": "transfer_rel_err: full-sphere relative L2 of the world-frame transfer"}
    metrics: dict[str, Any] = {}
    paths = []
    for array in arrays:
        y = train.extra[array]
        red = reduce_transfer(train, y, ds.cluster, tcfg, cfg, train_only)
        log_progress(progress, f"{array}: input PCA {ds.n_features} -> {red.inp.n_components} dims "
                       f"({red.inp.retained:.3f}); output PCA {tcfg.output_pca}: {red.out.n_groups} group(s), "
                       f"width {red.out.width}")
        fits = fit_transfer(red, tcfg, cfg, progress)
        errs: dict[str, Any] = {"pca_floor": {"train": transfer_rel_err(red.out.expand(red.z), y)}}
        if held is not None:
            errs["pca_floor"]["heldout"] = transfer_rel_err(red.out.expand(red.out.reduce(held.extra[array])),
                                                            held.extra[array])
        for kind, r in fits.items():
            path = run.transfer_model_path(kind, array)
            path.parent.mkdir(parents=True, exist_ok=True)
            save_model(r.model, path)
            paths.append(path)
            errs[kind] = {"fit_s": r.fit_s, "train": transfer_rel_err(r.model.predict(train.pose).numpy(), y)}
            if held is not None:
                errs[kind]["heldout"] = transfer_rel_err(r.model.predict(held.pose).numpy(), held.extra[array])
        metrics[array] = errs
        meta["arrays"][array] = {"order": int(round(y.shape[2] ** 0.5)), "n_coeffs": int(y.shape[2]),
                                 "output_pca": tcfg.output_pca, **_reduction_meta(red),
                                 "fit": {k: {"fit_s": r.fit_s, **r.choice} for k, r in fits.items()},
                                 "transfer_rel_err": errs}
    meta["files"] = run.unit_hashes(paths)
    atomic_write_json(run.transfer_json, meta)
    return metrics


def fit_stage(ds: BakedDataset, run: RunDir, cfg: TrainConfig, splits: dict[str, SplitData],
              progress: Any = None) -> dict[str, Any] | None:
    """The :class:`~prt_torch.fit.stages.FitHook` call: :func:`train_transfer` (it reads its own arrays from the
    store: ``splits`` is not needed). Returns ``metrics.json``'s ``transfer`` entry, ``None`` without
    ``train.transfer``."""
    return train_transfer(ds, run, cfg, progress)


#: ``prt train``'s ``train.transfer`` step (:data:`prt_torch.fit.stages.FIT_STAGES`)
FIT_HOOK = FitHook(section="transfer", metrics_key="transfer", run=fit_stage)

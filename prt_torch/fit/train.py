"""Training: reduce, cross-validate and fit every model kind, write the run's model files.

``train(config)`` reads the run's baked dataset (the ``train`` split, and ``heldout`` for the metrics
when present) and writes into the run directory (:class:`prt_torch.rundir.RunDir` names the files)::

    models/<kind>.pt     one VisibilityModel per kind (packed state dict + config)
    model.pt             the default kind (mlp when trained): a hard link, not a second copy
    model.json           metadata: conventions, order, V, A, kinds, dataset/character hash,
                         chosen alphas/neurons per cluster, CV scores, fit times, and ``files``:
                         the sha256 of every file above and of metrics.json
    metrics.json         visibility errors per kind on train and held-out frames, and one entry per method
                         hook that ran (:data:`prt_torch.fit.stages.FIT_STAGES`: ``train.transfer``,
                         ``train.local``, ``train.s001``, each writing its own files)

The fit runs on ``train.device`` (:mod:`prt_torch.fit.device`: the CPU reference path, or CUDA); the models
are always assembled and saved on the CPU.

One committed unit: the stage first drops its ``stages.json`` key and stale temporaries
(:meth:`RunDir.begin`), writes the models, the default link and the metrics (each atomically), then
``model.json`` LAST (the commit record), then its ``stages.json`` key. A kill before ``model.json`` is
renamed leaves files that disagree with the old ``model.json``: every reader (:meth:`RunDir.model_meta`,
:func:`prt_torch.models.load_model`, ``prt eval``) refuses them with one line saying to re-run ``prt train``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import torch

from prt_torch.bake.store import BakedDataset, SplitData, open_dataset
from prt_torch.errors import MissingArtifact, check
from prt_torch.fit.config import TrainConfig
from prt_torch.fit.device import resolve_device
from prt_torch.fit.inputs import load_skinning
from prt_torch.fit.kinds import FitResult, Reduced, cv_train_only, fit_kinds, log_progress, reduce_training
from prt_torch.fit.stages import fit_hooks
from prt_torch.io import atomic_write_json
from prt_torch.metrics import vis_rel_err
from prt_torch.models import (
    VisibilityModel,
    link_default,
    save_model,
)
from prt_torch.rundir import RunDir, stage_key


def predict(model: VisibilityModel, pose: np.ndarray) -> np.ndarray:
    """``(F, A)`` -> ``(F, V, C)`` numpy float32."""
    return model.predict(pose).numpy()


def _metadata(info: BakedDataset, cfg: TrainConfig, red: Reduced, fits: dict[str, FitResult], default: str,
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
        "input_selection": cfg.input_selection,
        "selected_inputs": None if red.sel is None else int(red.sel.proj.shape[1]),
        "input_retained": red.inp.retained,
        "output_pca": cfg.output_pca,
        "output_dims": red.out.dims.tolist(),
        "output_width": red.out.width,
        "n_clusters": red.out.n_groups,
        "kinds": list(fits),
        "default_kind": default,
        "dataset": str(info.path.resolve()),
        "character_hash": info.character_hash,
        "train_clips": train.clips,
        "train_frames": train.n_frames,
        "train_config": cfg.model_dump(),
        "fit_device": resolve_device(cfg.device),
        "fit": {k: {"fit_s": r.fit_s, **r.choice} for k, r in fits.items()},
    }


def unit_files(run: RunDir, kinds: list[str], peaks: bool = False) -> list[Path]:
    """The files of the train unit besides ``model.json``: each kind's model, the default model, the metrics (and
    with ``train.peaks`` the learned peak blockers). ``model.json`` records their sha256 (``files``) and is
    written after them: it commits the unit."""
    return [*(run.model_path(k) for k in kinds), run.model_path(), run.metrics_json,
            *((run.peak_blockers_path,) if peaks else ())]


def train_key(ds: BakedDataset, cfg: TrainConfig) -> str:
    """The ``train`` stage key: the training settings and the dataset's content key. ``device`` enters as the
    device it resolves to, and only when that is not the CPU: a CPU fit (``auto`` without a GPU, or ``cpu``) is
    the reference path, bit-identical to fits from before the setting existed, so their keys stay valid; a CUDA
    fit agrees with it only to rounding, so it is keyed apart (``cuda`` without a GPU: one-line PrtError)."""
    settings = cfg.model_dump(mode="json")
    settings.pop("device")
    for hook in fit_hooks():  # keys of runs trained before a method's section (train.transfer ...) existed stay valid
        if settings.get(hook.section) is None:
            settings.pop(hook.section, None)
    for cap in ("output_max_components", "input_max_components", "peaks"):  # likewise the size caps, train.peaks
        if settings.get(cap) is None:
            settings.pop(cap, None)
    device = resolve_device(cfg.device)
    if device != "cpu":
        settings["device"] = device
    return stage_key({"train": settings, "dataset": ds.key()})


def train_dataset(dataset: str | Path | BakedDataset, run_dir: str | Path | RunDir, cfg: TrainConfig | None = None,
                  progress: Any = None) -> dict[str, Any]:
    """Train every kind on ``dataset`` and write the run files into ``run_dir``; returns metrics."""
    cfg = cfg or TrainConfig()
    resolve_device(cfg.device)  # cuda without a GPU fails here, before the run's train stage is touched
    run = RunDir.of(run_dir)
    ds = dataset if isinstance(dataset, BakedDataset) else open_dataset(dataset)
    torch.manual_seed(cfg.seed)
    threads = torch.get_num_threads()
    if cfg.threads:
        # the L-BFGS two-loop recursion is many tiny vector ops: thread sync dominates (10x on 2 busy cores)
        torch.set_num_threads(cfg.threads)
    try:
        with run.lock("train"):  # one writer per run directory (a second one fails at once, naming the holder)
            if cfg.threads:
                from threadpoolctl import threadpool_limits

                with threadpool_limits(limits=cfg.threads):
                    return _train(ds, run, cfg, progress)
            return _train(ds, run, cfg, progress)
    finally:
        torch.set_num_threads(threads)


def _train(ds: BakedDataset, run: RunDir, cfg: TrainConfig, progress: Any) -> dict[str, Any]:
    hooks = [h for h in fit_hooks() if h.is_set(cfg)]  # the methods this training fits besides the visibility
    for hook in hooks:  # before anything is fitted or written
        if hook.check is not None:
            hook.check(ds, cfg)
    if cfg.peaks is not None:
        check_peak_data(ds)
    extra = tuple(dict.fromkeys(a for h in hooks for a in h.extra))  # the per-frame arrays the hooks read
    train = ds.split("train", extra=extra)
    check(train.n_frames >= 2 * cfg.folds, f"{ds.path}: only {train.n_frames} training frames for {cfg.folds} folds")
    # the stage's files; model.json (written last, with their sha256) commits them (see unit_files)
    run.begin("train", (*unit_files(run, cfg.kinds, cfg.peaks is not None), run.model_json))
    skinning = load_skinning(ds) if cfg.input_selection == "joints" else None
    train_only = cv_train_only(ds, train, cfg)
    red = reduce_training(train, ds.cluster, cfg, skinning, train_only)
    log_progress(progress, f"input PCA: {ds.n_features} -> {red.inp.n_components} dims ({red.inp.retained:.3f} "
                           f"variance); output PCA: {red.out.n_groups} clusters, "
                           f"dims {red.out.dims.min()}..{red.out.width}")
    fits = fit_kinds(red, cfg, progress)
    for kind, r in fits.items():
        save_model(r.model, run.model_path(kind))
    default = cfg.default_kind if cfg.default_kind in fits else next(iter(fits))
    link_default(run, default)
    meta = _metadata(ds, cfg, red, fits, default, train)
    metrics: dict[str, Any] = {"models": {}}
    splits = {"train": train}
    if "heldout" in ds.splits:
        try:
            splits["heldout"] = ds.split("heldout", extra=extra, max_frames=cfg.eval_frames)
        except MissingArtifact:  # no held-out frame baked yet
            pass
    for kind, r in fits.items():
        metrics["models"][kind] = {"fit_s": r.fit_s}
        for name, sp in splits.items():
            metrics["models"][kind][name] = {"vis_rel_err": vis_rel_err(predict(r.model, sp.pose), sp.visibility)}
    for name, sp in splits.items():
        metrics.setdefault("pca_floor", {})[name] = vis_rel_err(red.out.expand(red.out.reduce(sp.visibility)),
                                                               sp.visibility)
    for hook in fit_hooks():  # every hook: an unset one removes its stale files
        part = hook.run(ds, run, cfg, splits, progress)
        if part is not None:
            metrics[hook.metrics_key] = part
    if cfg.peaks is not None:
        metrics["peaks"] = fit_peaks(ds, run, cfg, progress)
    else:
        run.peak_blockers_path.unlink(missing_ok=True)  # not this training's: a previous one's
    atomic_write_json(run.metrics_json, metrics)
    meta["files"] = run.unit_hashes(unit_files(run, list(fits), cfg.peaks is not None))
    from prt_torch.kernels import kernel_state

    meta["blas_kernels"] = kernel_state()  # "pinned": the same fit on every x86-64 AVX2 machine (DESIGN.md)
    atomic_write_json(run.model_json, meta)  # the commit record: written last
    run.mark_done("train", train_key(ds, cfg))
    return metrics


def check_peak_data(ds: BakedDataset) -> None:
    """``train.peaks`` needs a dataset baked with ``bake.peaks`` (one-line error otherwise)."""
    from prt_torch.fit.peaks import has_peak_data

    check(has_peak_data(ds), f"{ds.path}: train.peaks needs peak visibility in the dataset: bake with bake.peaks set")


def fit_peaks(ds: BakedDataset, run: RunDir, cfg: TrainConfig, progress: Any) -> dict[str, Any]:
    """Fit and write the learned peak blockers (``train.peaks``, :mod:`prt_torch.fit.peaks`); their metrics."""
    from prt_torch.fit.peaks import PeakFitSettings, fit_peak_blockers

    pc = cfg.peaks
    assert pc is not None
    settings = PeakFitSettings(steps=pc.steps, frames_per_step=pc.frames_per_step,
                               vertices_per_step=pc.vertices_per_step, learning_rate=pc.learning_rate,
                               widen_deg=pc.widen_deg, anneal=pc.anneal, eval_frames=pc.eval_frames, seed=cfg.seed,
                               blockers=pc.blockers, capsules_per_bone=pc.capsules_per_bone, weight=pc.weight)
    done = ds.done
    rows = {s: np.intersect1d(ds.split_rows(s), np.flatnonzero(done)) if s in ds.splits else np.zeros(0, np.int64)
            for s in ("train", "heldout")}
    n = pc.spheres if pc.spheres is not None else ds.bake_config().blockers
    character = ds.character()
    what = f"{pc.capsules_per_bone:g} capsules per bone" if pc.blockers == "capsules" else f"{n} spheres"
    log_progress(progress, f"peak blockers: fitting {what} to the exact peak visibility of "
                           f"{len(rows['train'])} frames ({settings.steps} steps)")
    model, metrics = fit_peak_blockers(ds, character, rows["train"], rows["heldout"], n, settings)
    model.save(run.peak_blockers_path)
    log_progress(progress, f"peak blockers: wrong side of 0.5 {metrics['initial']['wrong_side']:.2%} (rest "
                           f"{pc.blockers}) -> {metrics['learned']['wrong_side']:.2%} (learned) on "
                           f"{metrics['eval_frames']} {metrics['eval_split']} frames, {metrics['fit_s']:.0f} s")
    return metrics


def dataset_of(config: Any) -> Path:
    """The dataset a run config trains on: ``train.dataset`` when set, else the run's own."""
    return config.resolve(config.train.dataset) if config.train.dataset else RunDir(config.out_dir).dataset_path


def train(config: Any, progress: Any = None) -> RunDir:
    """Train from a :class:`prt_torch.config.RunConfig`; returns the run directory."""
    run = RunDir(config.out_dir)
    train_dataset(dataset_of(config), run, config.train, progress)
    return run

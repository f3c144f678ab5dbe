"""Evaluate a trained run against baked ground truth: metrics per model kind and split.

For every kind (and the ``noshadow`` baseline: unoccluded hemisphere visibility) and each split
(``train``, ``heldout``): ``vis_rel_err`` (relative SH L2 = relative integrated squared error),
``transfer_rel_err`` and ``transfer_err`` (seed 000 section 6, hemisphere about the normal),
``psnr_diffuse``/``psnr_glossy`` and ``rmse_diffuse``/``rmse_glossy`` (relative RMSE) of shaded
radiance averaged over the environment lights, per light in ``per_light``, and ``jitter``
(per clip, frame-to-frame, see :func:`prt_torch.metrics.jitter`).
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from prt_torch.errors import PrtError
from prt_torch import metrics as M
from prt_torch.eval.shading import (
    default_lights,
    lambert_rpo,
    phong_rpo,
    shade,
    shading_set,
    unshadowed_visibility,
)
from prt_torch.fit.data import SplitData, load_split
from prt_torch.models import KINDS, load_metadata, load_model
from prt_torch.models.storage import storage_table


@dataclass
class Evaluation:
    """Everything ``prt eval`` computes (``results`` is the JSON-able summary)."""

    results: dict[str, Any]
    splits: dict[str, SplitData] = field(default_factory=dict)
    predictions: dict[str, dict[str, np.ndarray]] = field(default_factory=dict)  # split -> kind -> (F, V, C)
    shading: dict[str, dict[str, np.ndarray]] = field(default_factory=dict)  # split -> "light/rpo" -> a
    lights: dict[str, np.ndarray] = field(default_factory=dict)


def shared_data_dir() -> Path | None:
    """``$PRT_SHARED/data`` or ``../shared/data`` next to the repository, when present."""
    env = os.environ.get("PRT_SHARED")
    cands = [Path(env) / "data"] if env else []
    cands.append(Path(__file__).resolve().parents[2].parent / "shared" / "data")
    cands.append(Path.cwd().parent / "shared" / "data")
    return next((c for c in cands if c.is_dir()), None)


def _jitter_per_clip(pred: np.ndarray, truth: np.ndarray, clip_id: np.ndarray) -> float:
    vals, weights = [], []
    for c in np.unique(clip_id):
        sel = clip_id == c
        if sel.sum() >= 2:
            vals.append(M.jitter(pred[sel], truth[sel]))
            weights.append(sel.sum() - 1)
    return float(np.average(vals, weights=weights)) if vals else 0.0


def split_metrics(pred: np.ndarray, truth: np.ndarray, clip_id: np.ndarray,
                  shading: dict[str, np.ndarray]) -> dict[str, Any]:
    """All metrics of one prediction ``(F, V, C)`` against ``truth``."""
    te = M.transfer_error(pred, truth)
    te_ref = M.transfer_error(np.zeros_like(truth), truth)
    out: dict[str, Any] = {
        "vis_rel_err": M.vis_rel_err(pred, truth),
        "transfer_err": float(te.mean()),
        "transfer_rel_err": float(np.sqrt(te.sum() / max(te_ref.sum(), 1e-30))),
        "jitter": _jitter_per_clip(pred, truth, clip_id),
        "per_light": {},
    }
    acc: dict[str, list[float]] = {}
    for key, a in shading.items():
        light, rpo = key.split("/")
        lt, lp = shade(truth, a), shade(pred, a)
        p, r = M.psnr(lp, lt), M.rel_rmse(lp, lt)
        out["per_light"].setdefault(light, {})[f"psnr_{rpo}"] = p
        out["per_light"][light][f"rmse_{rpo}"] = r
        acc.setdefault(f"psnr_{rpo}", []).append(p)
        acc.setdefault(f"rmse_{rpo}", []).append(r)
    for k, v in acc.items():
        out[k] = float(np.mean(v))
    return out


def evaluate_run(run_dir: str | Path, dataset: str | Path | None = None, max_frames: int | None = 32,
                 kinds: list[str] | None = None, shared_data: Path | None = None,
                 progress: Any = None) -> Evaluation:
    """Evaluate every trained kind of ``run_dir`` on up to ``max_frames`` frames per split."""
    run_dir = Path(run_dir)
    meta = load_metadata(run_dir)
    dataset = Path(dataset) if dataset is not None else Path(meta["dataset"])
    if not dataset.exists():
        cand = run_dir / "dataset.zarr"
        if cand.exists():
            dataset = cand
        else:
            raise PrtError(f"dataset not found: {dataset} (pass --dataset)")
    kinds = [k for k in (kinds or meta["kinds"]) if k in KINDS]
    models = {k: load_model(run_dir, k) for k in kinds}
    order = int(meta["order"])
    shared = shared_data if shared_data is not None else shared_data_dir()
    lights = default_lights(order, shared)
    rpos = {"diffuse": lambert_rpo(order), "glossy": phong_rpo(order)}
    ev = Evaluation(results={"run": str(run_dir), "dataset": str(dataset), "lights": list(lights),
                             "rpos": {k: r.name for k, r in rpos.items()}, "models": {}}, lights=lights)
    for split in ("train", "heldout"):
        try:
            sp = load_split(dataset, split, extra=("frames", "positions"), max_frames=max_frames, contiguous=True)
        except PrtError as exc:
            if split == "heldout" and "no split" in str(exc):
                continue
            raise
        ev.splits[split] = sp
        if progress is not None:
            progress.console.log(f"{split}: {sp.n_frames} frames, shading under {len(lights)} lights x 2 RPOs")
        sh = shading_set(sp.extra["frames"], lights, rpos)
        ev.shading[split] = sh
        preds = {k: m.predict(sp.pose).numpy() for k, m in models.items()}
        preds["noshadow"] = unshadowed_visibility(sp.visibility.shape[1], order, sp.n_frames)
        ev.predictions[split] = preds
        for kind, p in preds.items():
            ev.results["models"].setdefault(kind, {})[split] = split_metrics(p, sp.visibility, sp.clip_id, sh)
    table = storage_table(models, int(meta["train_frames"]))
    ev.results["storage"] = {k: v for k, v in table.items() if not k.startswith("_")}
    ev.results["storage_reference"] = table["_reference"]
    ev.results["fit"] = {k: {"fit_s": v.get("fit_s"), "alpha": v.get("alpha"), "neurons": v.get("neurons")}
                         for k, v in meta.get("fit", {}).items()}
    ev.results["targets"] = targets(ev.results)
    return ev


def targets(results: dict[str, Any]) -> dict[str, Any]:
    """The issue's targets on held-out frames: MLP error <= 0.7x linear, PSNR >= 40 / 35 dB."""
    m = results["models"]
    if "heldout" not in m.get("mlp", {}) or "heldout" not in m.get("linear", {}):
        return {}
    mlp, lin = m["mlp"]["heldout"], m["linear"]["heldout"]
    ratio = mlp["vis_rel_err"] / max(lin["vis_rel_err"], 1e-30)
    return {"mlp_over_linear": ratio, "mlp_over_linear_ok": ratio <= 0.7,
            "psnr_diffuse": mlp.get("psnr_diffuse"), "psnr_diffuse_ok": mlp.get("psnr_diffuse", 0) >= 40,
            "psnr_glossy": mlp.get("psnr_glossy"), "psnr_glossy_ok": mlp.get("psnr_glossy", 0) >= 35}

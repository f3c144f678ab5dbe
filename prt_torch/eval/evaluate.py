"""Evaluate a trained run against its baked ground truth, on the shipping path (``prt eval``).

For every trained kind (torch models) and ``unshadowed`` (the player's unoccluded hemisphere
visibility), on each split: every done held-out frame (``max_frames`` caps it, first frames of each
clip), and the training split subsampled to ``train_frames`` (contiguous runs per clip so that the
frame-to-frame jitter stays meaningful). Visibility errors are
``vis_rel_err`` (relative SH L2 = relative integrated squared error), ``transfer_err`` /
``transfer_rel_err`` (seed 000 section 6, hemisphere about the normal) and ``jitter``
(per clip, :func:`prt_torch.metrics.jitter`). Shading uses :mod:`prt_torch.scoring` (the RPO
catalogue ``prt export`` ships, ``shade_rpo``, the player's lighting by both lighting paths, the player's
camera, renderer and tone map for images).

JSON schema (``RUN/report/results.json``; ``prt eval --json`` prints the same object)::

    {
      "run": str, "dataset": str,
      "frames": {split: n},            # frames scored per split (every done held-out frame by default)
      "image_frames": {split: n},      # frames rendered for image PSNR (a subset, evenly spaced)
      "train_subsampled": bool,        # the training split was subsampled
      "lights": {light: {"source": str, "zh_rel_error": x}},
      "brdfs": [...], "paths": ["exact", "lobes"], "player_light": "sky",
      "models": {kind|"unshadowed": {split: {
          "frames": n, "vis_rel_err": x, "transfer_err": x, "transfer_rel_err": x, "jitter": x,
          "shading": {light: {brdf: {path: {"radiance_rel_rmse": x, "psnr_vertex": x, "psnr_image": x|null}}}},
          # flat summaries: the player's light (sky), lobes path, lambert = diffuse, phong = glossy
          "psnr_diffuse": x, "psnr_glossy": x,              # image PSNR (dB)
          "psnr_vertex_diffuse": x, "psnr_vertex_glossy": x, # vertex-radiance PSNR (dB)
          "rmse_diffuse": x, "rmse_glossy": x}}},           # vertex-radiance relative RMSE
      "lobe_fit": {split: {light: {brdf: {"radiance_rel_rmse", "psnr_vertex", "psnr_image"}}}},
                                       # truth shaded by the lobes path vs the exact path: the ZH fit alone
      "storage": {kind: {...}}, "storage_reference": {...}, "fit": {...}, "targets": {...}
    }

``psnr_image`` is pooled over the rendered frames (one MSE over every masked pixel of every image
frame), ``null`` when the dataset has no faces to render. The dataset is the run's own, else the one recorded
at training time (named in a warning line), and must be of the model's character; the images need the
``character.npz`` beside it (missing or another character: a one-line error).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from prt_torch import metrics as M
from prt_torch.bake.store import BakedDataset, SplitData
from prt_torch.errors import PrtError, check
from prt_torch.models import KINDS
from prt_torch.models.storage import storage_table
from prt_torch.rundir import RunDir
from prt_torch.scoring.images import FrameImages, ImageRenderer, player_camera
from prt_torch.scoring.lighting import PATHS, PLAYER_LIGHT, shared_data_dir, shipping_lights, unshadowed_visibility
from prt_torch.scoring.rpos import BRDFS, DIFFUSE, GLOSSY, shipping_rpos
from prt_torch.scoring.sampling import evenly_spaced
from prt_torch.scoring.shading import ShippingShader
from prt_torch.scoring.statistics import ImageStats, RadianceStats

UNSHADOWED = "unshadowed"
#: default cap of the training split (it is only a sanity check of the fit)
TRAIN_FRAMES = 48
#: default number of frames rendered per split for image PSNR
IMAGE_FRAMES = {"heldout": 6, "train": 3}


@dataclass
class Evaluation:
    """Everything ``prt eval`` computes (``results`` is the JSON-able summary, schema in the module docstring).

    ``predictions[split][kind] (F, V, C)``; ``report_frame[split]`` = (frame index within the split, its
    images under the player's light, diffuse BRDF, lobes path: truth and every prediction)."""

    results: dict[str, Any]
    dataset: BakedDataset | None = None
    splits: dict[str, SplitData] = field(default_factory=dict)
    predictions: dict[str, dict[str, np.ndarray]] = field(default_factory=dict)
    report_frame: dict[str, tuple[int, FrameImages]] = field(default_factory=dict)


def _jitter_per_clip(pred: np.ndarray, truth: np.ndarray, clip_id: np.ndarray) -> float:
    vals, weights = [], []
    for c in np.unique(clip_id):
        sel = clip_id == c
        if sel.sum() >= 2:
            vals.append(M.jitter(pred[sel], truth[sel]))
            weights.append(sel.sum() - 1)
    return float(np.average(vals, weights=weights)) if vals else 0.0


def visibility_metrics(pred: np.ndarray, truth: np.ndarray, clip_id: np.ndarray) -> dict[str, float]:
    """``vis_rel_err``, ``transfer_err``, ``transfer_rel_err`` and ``jitter`` of ``pred (F, V, C)`` vs ``truth``."""
    te = M.transfer_error(pred, truth)
    te_ref = M.transfer_error(np.zeros_like(truth), truth)
    return {"vis_rel_err": M.vis_rel_err(pred, truth), "transfer_err": float(te.mean()),
            "transfer_rel_err": float(np.sqrt(te.sum() / max(te_ref.sum(), 1e-30))),
            "jitter": _jitter_per_clip(pred, truth, clip_id)}


def _character(ds: BakedDataset) -> Any:
    """The dataset's character for the rendered images (:meth:`BakedDataset.character`: the ``character.npz``
    beside it, hash-checked; missing or another character is a :class:`PrtError`); ``None`` when the dataset has no
    faces to render."""
    if len(ds.faces) == 0:
        return None
    character = ds.character()
    check(character.num_vertices == ds.n_vertices,
          f"{ds.path}: {ds.n_vertices} vertices, its character {character.num_vertices}")
    return character


def evaluate_run(run_dir: str | Path | RunDir, dataset: str | Path | None = None, max_frames: int | None = None,
                 train_frames: int | None = TRAIN_FRAMES, kinds: list[str] | None = None,
                 shared_data: Path | None = None, lights: list[str] | None = None,
                 image_frames: dict[str, int] | None = None, log: Callable[[str], None] | None = None,
                 progress: bool = False) -> Evaluation:
    """Evaluate every trained kind of ``run_dir`` (see the module docstring).

    Args:
        run_dir: the run (``model.json``, ``models/<kind>.pt``).
        dataset: the dataset (default: the run's, else the one recorded in ``model.json``).
        max_frames: cap per split (first frames of each clip); ``None``: every done frame.
        train_frames: cap of the training split (``None``: every frame).
        kinds: model kinds (default: every trained kind).
        shared_data: ``../shared/data`` for the env-map lights (default :func:`shared_data_dir`).
        lights: restrict the lights (names of :func:`prt_torch.scoring.lighting.shipping_lights`).
        image_frames: frames rendered per split for image PSNR (default :data:`IMAGE_FRAMES`; 0 disables).
        log: a callable for one-line progress notes (e.g. ``console.log``).
        progress: show a rich progress bar while shading and rendering.
    """
    run = RunDir.of(run_dir).require()
    meta = run.model_meta()
    ds = run.resolve_dataset(meta, dataset)
    kinds = [k for k in (kinds or meta["kinds"]) if k in KINDS]
    check(len(kinds) > 0, f"no trained model kinds in {run.path}")
    models = {k: run.model(k) for k in kinds}
    order = ds.order
    shared = shared_data if shared_data is not None else shared_data_dir()
    light_set = shipping_lights(order, shared, names=lights)
    rpos = shipping_rpos(order, run)
    character = _character(ds)
    can_render = character is not None
    camera = player_camera(character) if character is not None else None
    eye = camera.eye if camera is not None else np.array([0.0, -5.0, 1.0])
    shader = ShippingShader(light_set, rpos, eye)
    n_img = dict(IMAGE_FRAMES if image_frames is None else image_frames)
    note = log or (lambda s: None)
    ev = Evaluation(results={
        "run": str(run.path), "dataset": str(ds.path), "frames": {}, "image_frames": {}, "train_subsampled": False,
        "lights": {n: {"source": lt.source, "zh_rel_error": lt.rel_error} for n, lt in light_set.items()},
        "brdfs": list(rpos), "paths": list(PATHS), "player_light": PLAYER_LIGHT, "models": {}, "lobe_fit": {}},
        dataset=ds)
    renderer = ImageRenderer(character.rest_vertices, ds.faces, camera) if can_render else None
    try:
        for split in ("train", "heldout"):
            if split not in ds.splits or len(ds.split_rows(split)) == 0:
                if split == "train":
                    raise PrtError(f"{ds.path}: split 'train' has no baked frames")
                continue
            cap = max_frames
            if split == "train" and train_frames is not None:
                cap = train_frames if cap is None else min(cap, train_frames)
            total = len(ds.split_rows(split))
            sp = ds.split(split, extra=("frames", "positions"), max_frames=cap, contiguous=True)
            if split == "train" and sp.n_frames < total:
                ev.results["train_subsampled"] = True
            ev.splits[split] = sp
            ev.results["frames"][split] = sp.n_frames
            preds = {k: m.predict(sp.pose).numpy() for k, m in models.items()}
            preds[UNSHADOWED] = np.broadcast_to(unshadowed_visibility(order, ds.attrs), sp.visibility.shape)
            ev.predictions[split] = preds
            res = {k: {"frames": sp.n_frames, **visibility_metrics(p, sp.visibility, sp.clip_id)}
                   for k, p in preds.items()}
            per_frame_gap = M.per_frame_rel_err(preds[UNSHADOWED], sp.visibility)
            report_f = int(np.argmax(per_frame_gap))
            img_idx = evenly_spaced(sp.n_frames, n_img.get(split, 0), must=[report_f]) if renderer else \
                np.zeros(0, np.int64)
            ev.results["image_frames"][split] = int(len(img_idx))
            note(f"{split}: {sp.n_frames} of {total} frames, {len(light_set)} lights x {len(rpos)} BRDFs x "
                 f"{len(PATHS)} lighting paths; {len(img_idx)} frames rendered")
            shading = _shade_split(shader, sp, preds, img_idx, renderer, report_f, progress)
            for k in preds:
                res[k]["shading"] = shading["models"][k]
                res[k].update(_flat_summary(res[k]["shading"]))
                ev.results["models"].setdefault(k, {})[split] = res[k]
            ev.results["lobe_fit"][split] = shading["lobe_fit"]
            if shading["report"] is not None:
                ev.report_frame[split] = (report_f, shading["report"])
    finally:
        if renderer is not None:
            renderer.close()
    table = storage_table(models, int(meta["train_frames"]))
    ev.results["storage"] = {k: v for k, v in table.items() if not k.startswith("_")}
    ev.results["storage_reference"] = table["_reference"]
    ev.results["fit"] = {k: {"fit_s": v.get("fit_s"), "alpha": v.get("alpha"), "neurons": v.get("neurons")}
                         for k, v in meta.get("fit", {}).items()}
    ev.results["targets"] = targets(ev.results)
    return ev


def _shade_split(shader: ShippingShader, sp: SplitData, preds: dict[str, np.ndarray], img_idx: np.ndarray,
                 renderer: ImageRenderer | None, report_f: int, progress: bool) -> dict[str, Any]:
    """Vertex and image errors of every prediction under every (light, BRDF, path), and the lobe-fit error."""
    frames, positions = sp.extra["frames"], sp.extra["positions"]
    vis = {"truth": sp.visibility, **preds}
    combos = shader.combos
    rad_stats = {c: {k: RadianceStats() for k in preds} for c in combos}
    img_stats = {c: {k: ImageStats() for k in preds} for c in combos}
    lobe_rad: dict[tuple[str, str], RadianceStats] = {}
    lobe_img: dict[tuple[str, str], ImageStats] = {}
    keep = set(int(i) for i in img_idx)
    kept: dict[int, dict[tuple[str, str, str], dict[str, np.ndarray]]] = {}
    chunks = shader.chunks(sp.n_frames, sp.visibility.shape[1])
    bar = ProgressBar(progress, len(chunks) + len(keep), f"shading {sp.name}")
    try:
        for sl, res in shader.shade(vis, frames, positions):
            for c, d in res.items():
                for k in preds:
                    rad_stats[c][k].add(d[k], d["truth"])
            for ln in shader.lights:
                for bn in shader.rpos:
                    if ("exact" in shader.paths) and ("lobes" in shader.paths):
                        lobe_rad.setdefault((ln, bn), RadianceStats()).add(res[(ln, bn, "lobes")]["truth"],
                                                                           res[(ln, bn, "exact")]["truth"])
            for f in range(sl.start, sl.stop):
                if f in keep:
                    kept[f] = {c: {k: d[k][f - sl.start] for k in d} for c, d in res.items()}
            bar.advance()
        report: FrameImages | None = None
        for f in sorted(kept):
            pos = positions[f]
            mask = renderer.mask(pos)  # type: ignore[union-attr]
            for c in combos:
                fi = renderer.frame_images(pos, kept[f][c], "truth", mask=mask)  # type: ignore[union-attr]
                for k in preds:
                    img_stats[c][k].add(*fi.sse[k])
                if f == report_f and c == (PLAYER_LIGHT, DIFFUSE, "lobes"):
                    report = fi
            for ln in shader.lights:
                for bn in shader.rpos:
                    if ("exact" in shader.paths) and ("lobes" in shader.paths):
                        fi = renderer.frame_images(pos, {"exact": kept[f][(ln, bn, "exact")]["truth"],  # type: ignore
                                                         "lobes": kept[f][(ln, bn, "lobes")]["truth"]}, "exact",
                                                   mask=mask)
                        lobe_img.setdefault((ln, bn), ImageStats()).add(*fi.sse["lobes"])
            bar.advance()
    finally:
        bar.stop()
    models: dict[str, Any] = {k: {} for k in preds}
    for (ln, bn, p) in combos:
        for k in preds:
            r, im = rad_stats[(ln, bn, p)][k], img_stats[(ln, bn, p)][k]
            models[k].setdefault(ln, {}).setdefault(bn, {})[p] = {
                "radiance_rel_rmse": r.rel_rmse, "psnr_vertex": r.psnr, "psnr_image": im.psnr}
    lobe_fit: dict[str, Any] = {}
    for (ln, bn), r in lobe_rad.items():
        im = lobe_img.get((ln, bn), ImageStats())
        lobe_fit.setdefault(ln, {})[bn] = {"radiance_rel_rmse": r.rel_rmse, "psnr_vertex": r.psnr,
                                           "psnr_image": im.psnr}
    return {"models": models, "lobe_fit": lobe_fit, "report": report}


def _flat_summary(shading: dict[str, Any]) -> dict[str, Any]:
    """The flat keys: the player's light, lobes path (else exact), diffuse = lambert, glossy = phong."""
    light = shading.get(PLAYER_LIGHT) or next(iter(shading.values()))
    out: dict[str, Any] = {}
    for tag, brdf in (("diffuse", DIFFUSE), ("glossy", GLOSSY)):
        if brdf not in light:
            continue
        m = light[brdf].get("lobes") or light[brdf].get("exact")
        out[f"psnr_{tag}"] = m["psnr_image"]
        out[f"psnr_vertex_{tag}"] = m["psnr_vertex"]
        out[f"rmse_{tag}"] = m["radiance_rel_rmse"]
    return out


def targets(results: dict[str, Any]) -> dict[str, Any]:
    """The issue's targets on held-out frames: MLP error <= 0.7x linear; image PSNR >= 40 / 35 dB (diffuse /
    glossy, the player's light, lobes path)."""
    m = results["models"]
    if "heldout" not in m.get("mlp", {}) or "heldout" not in m.get("linear", {}):
        return {}
    mlp, lin = m["mlp"]["heldout"], m["linear"]["heldout"]
    ratio = mlp["vis_rel_err"] / max(lin["vis_rel_err"], 1e-30)
    pd, pg = mlp.get("psnr_diffuse"), mlp.get("psnr_glossy")
    return {"mlp_over_linear": ratio, "mlp_over_linear_ok": ratio <= 0.7,
            "psnr_diffuse": pd, "psnr_diffuse_ok": None if pd is None else pd >= 40,
            "psnr_glossy": pg, "psnr_glossy_ok": None if pg is None else pg >= 35}


class ProgressBar:
    """A rich progress bar (or nothing)."""

    def __init__(self, enabled: bool, total: int, label: str) -> None:
        self._p = None
        if enabled and total > 0:
            from prt_torch.progress import progress_bar

            self._p = progress_bar(transient=True)
            self._t = self._p.add_task(label, total=total)
            self._p.start()

    def advance(self) -> None:
        if self._p is not None:
            self._p.update(self._t, advance=1)

    def stop(self) -> None:
        if self._p is not None:
            self._p.stop()


__all__ = ["BRDFS", "Evaluation", "UNSHADOWED", "evaluate_run", "shared_data_dir", "targets", "visibility_metrics"]

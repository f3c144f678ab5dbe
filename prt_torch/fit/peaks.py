"""Fit the learned peak blockers (:class:`prt_torch.models.peak_blockers.PeakBlockers`) to the bake's exact peak
visibility (``bake.peaks``: ``peak_directions``, ``peak_visibility`` per frame).

* **Data**: the train split's frames, each with its posed positions, frame normals, skinning matrices (the bake's
  own plan of the recorded config, :func:`prt_torch.bake.plan.make_plan`: random poses included) and its ``D``
  recorded discs.
* **Initialisation**: ``blockers = "spheres"``: rest-mesh spheres (:func:`~prt_torch.blockers.spheres.fit_spheres`,
  ``n_spheres`` of them), so the model starts as ``peaks_spheres``; ``"capsules"``: rest-mesh capsules
  (:func:`~prt_torch.blockers.capsules.fit_capsules`), ``capsules_per_bone`` x the bones with vertices of them (one
  per bone, the extra ones splitting the bones with most vertices along their axes), each endpoint and radius then
  learned.
* **Loss**: the mean squared error of the visible fractions over random batches (``frames_per_step`` frames, all
  their discs, ``vertices_per_step`` random vertices), Adam on each sphere's centre offset and log radius scale;
  ``weight = "cosine"`` weights each vertex-disc pair's error by ``max(n . l, 0)``, the peak term's own factor, so
  the fit spends the blockers where a shadow changes the image (a grazing pair's error barely shows).
  The kernel's penumbra is the disc's, so a sun-sized disc has almost no gradient away from the shadow's edge: the
  discs are widened during the fit (``widen_deg``, annealed linearly to the recorded radius over the first
  ``anneal`` share of the steps). A widened disc's half-shadow sits where the sharp shadow's edge is, so the edge
  the fit learns is the right one.
* **Result**: the step with the lowest validation error (``shading_rmse`` with the cosine weight, else the mean
  absolute error) on ``eval_frames`` train frames set apart from the fit (a fifth of them at most) is kept: the
  held-out frames choose nothing. The metrics report, on ``eval_frames`` held-out frames (the validation frames when
  none are baked), the initial blockers' and the learned ones' mean absolute error, the share of vertex-disc pairs
  on the wrong side of 0.5 and the shading-weighted RMSE (:func:`peak_errors`).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import Any

import numpy as np

from prt_torch.errors import PrtError, check


@dataclass(frozen=True)
class PeakFitSettings:
    """The fit's settings (``train.peaks``; module doc)."""

    steps: int = 400
    frames_per_step: int = 8
    vertices_per_step: int = 4096
    learning_rate: float = 0.02
    widen_deg: float = 4.0
    anneal: float = 0.6
    eval_frames: int = 16
    seed: int = 0
    blockers: str = "spheres"
    capsules_per_bone: float = 1.0
    weight: str = "uniform"


@dataclass
class PeakData:
    """``positions (F, V, 3)``, ``normals (F, V, 3)``, ``skin (F, J, 4, 4)`` float32, ``directions (F, D, 3)``,
    ``visibility (F, V, D)`` float32 and the recorded disc half-angle (radians)."""

    positions: np.ndarray
    normals: np.ndarray
    skin: np.ndarray
    directions: np.ndarray
    visibility: np.ndarray
    angular_radius: float


def has_peak_data(ds: Any) -> bool:
    """Whether the dataset records peak visibility (``bake.peaks``)."""
    return bool(ds.attrs.get("bake", {}).get("peaks")) and "peak_visibility" in ds


def plan_skin(ds: Any, character: Any) -> np.ndarray:
    """``(F, J, 4, 4)`` skinning matrices of every dataset row: the bake's plan of the recorded run config (the
    frames it posed, random poses included), checked against the stored pose features."""
    from prt_torch.bake.plan import make_plan

    cfg = ds.run_config()
    check(cfg is not None, f"{ds.path}: records no run config (the peak fit poses the bake's plan)")
    plan = make_plan(cfg, character)
    check(plan.n_frames == ds.n_frames and np.allclose(plan.pose, ds.pose, atol=1e-4),
          f"{ds.path}: the recorded config's plan is not this dataset's frames")
    return plan.skin


def load_peak_data(ds: Any, character: Any, rows: np.ndarray) -> PeakData:
    """The peak data of dataset rows ``rows`` (done frames)."""
    check(has_peak_data(ds), f"{ds.path}: records no peak visibility (bake.peaks)")
    d = ds.rows(rows, ("positions", "frames", "peak_directions", "peak_visibility"))
    skin = plan_skin(ds, character)[rows]
    rad = math.radians(float(ds.attrs["bake"]["peaks"]["angular_radius_deg"]))
    return PeakData(d["positions"].astype(np.float32), np.ascontiguousarray(d["frames"][..., 2, :], np.float32),
                    skin.astype(np.float32), d["peak_directions"].astype(np.float32),
                    d["peak_visibility"].astype(np.float32), rad)


def _predict(model: Any, data: PeakData, idx: np.ndarray, radius: float, verts: np.ndarray | None = None) -> Any:
    """``(B, V', D)`` predictions for frames ``idx`` (each frame its own directions; ``verts``: a vertex subset)."""
    import torch

    out = []
    for f in idx:
        pos = torch.from_numpy(data.positions[f] if verts is None else data.positions[f, verts])[None]
        nrm = torch.from_numpy(data.normals[f] if verts is None else data.normals[f, verts])[None]
        dirs = torch.from_numpy(data.directions[f])
        out.append(model(pos, nrm, torch.from_numpy(data.skin[f])[None], dirs,
                         torch.full((len(dirs),), radius, dtype=torch.float32)))
    return torch.cat(out, 0)


def shading_weight(normals: np.ndarray, directions: np.ndarray) -> np.ndarray:
    """``(F, V, D)`` ``max(n . l, 0)`` of frames' normals ``(F, V, 3)`` and discs ``(F, D, 3)``: how much a
    vertex-disc pair's visibility moves a Lambert vertex's radiance (the peak term's cosine)."""
    return np.clip(np.einsum("fvk,fdk->fvd", normals, directions), 0.0, None).astype(np.float32)


def peak_errors(pred: np.ndarray, target: np.ndarray, weight: np.ndarray | None = None) -> dict[str, float]:
    """``{"mean_abs_err", "wrong_side"}``: the mean absolute error of visible fractions and the share of pairs on
    the other side of 0.5 from the target; with ``weight`` (:func:`shading_weight`) also ``"shading_rmse"``, the
    root mean square of ``weight x (pred - target)``: the peak term's radiance error in units of the peak's
    irradiance (what the image PSNR sees)."""
    p, t = np.asarray(pred, np.float64), np.asarray(target, np.float64)
    out = {"mean_abs_err": float(np.abs(p - t).mean()), "wrong_side": float(((p > 0.5) != (t > 0.5)).mean())}
    if weight is not None:
        out["shading_rmse"] = float(np.sqrt(np.mean((np.asarray(weight, np.float64) * (p - t)) ** 2)))
    return out


def fit_peak_blockers(ds: Any, character: Any, train_rows: np.ndarray, eval_rows: np.ndarray, n_spheres: int,
                      settings: PeakFitSettings | None = None, progress: Any = None) -> tuple[Any, dict[str, Any]]:
    """Fit :class:`~prt_torch.models.peak_blockers.PeakBlockers` (module doc); returns ``(model, metrics)``."""
    import torch

    from prt_torch.blockers.capsules import fit_capsules
    from prt_torch.blockers.spheres import fit_spheres, vertex_bones
    from prt_torch.models.peak_blockers import PeakBlockers

    settings = settings or PeakFitSettings()
    check(settings.blockers in ("spheres", "capsules"),
          f"peak blockers must be 'spheres' or 'capsules', got {settings.blockers!r}")
    check(len(train_rows) > 0, "peak blockers: no baked train frames with peak visibility")
    t0 = time.perf_counter()
    check(settings.weight in ("uniform", "cosine"), f"peak fit weight must be 'uniform' or 'cosine', got "
                                                     f"{settings.weight!r}")
    rng = np.random.default_rng(settings.seed)
    train_rows = np.asarray(train_rows)
    # the step kept is chosen on train frames set apart from the fit (never on the held-out frames it is scored on)
    n_val = min(settings.eval_frames, len(train_rows) // 5)
    val_pick = np.zeros(len(train_rows), bool)
    val_pick[rng.choice(len(train_rows), n_val, replace=False)] = True
    train = load_peak_data(ds, character, train_rows[~val_pick])
    val = load_peak_data(ds, character, train_rows[val_pick]) if n_val else train
    val_idx = np.arange(len(val.positions)) if n_val else np.sort(
        rng.choice(len(train.positions), min(settings.eval_frames, len(train.positions)), replace=False))
    ev = load_peak_data(ds, character, eval_rows) if len(eval_rows) else None
    ev_idx = (np.sort(rng.choice(len(ev.positions), min(settings.eval_frames, len(ev.positions)), replace=False))
              if ev is not None else None)
    torch.manual_seed(settings.seed)
    check(settings.capsules_per_bone >= 1.0, f"capsules per bone must be >= 1, got {settings.capsules_per_bone!r}")
    if settings.blockers == "capsules":
        n_bones = int(np.unique(vertex_bones(character.joints, character.weights)).size)
        n_caps = min(round(settings.capsules_per_bone * n_bones), int(character.num_vertices))
        model = PeakBlockers(fit_capsules(character, max(n_caps, n_bones), seed=settings.seed))
    else:
        model = PeakBlockers(fit_spheres(character, min(int(n_spheres), int(character.num_vertices))))
    opt = torch.optim.Adam(model.parameters(), lr=settings.learning_rate)
    V = train.positions.shape[1]
    nv = min(settings.vertices_per_step, V)
    cosine = settings.weight == "cosine"
    key = "shading_rmse" if cosine else "mean_abs_err"

    def evaluate(data: PeakData, idx: np.ndarray) -> dict[str, float]:
        with torch.no_grad():
            pred = _predict(model, data, idx, data.angular_radius).numpy()
        return peak_errors(pred, data.visibility[idx], shading_weight(data.normals[idx], data.directions[idx]))

    initial = evaluate(val, val_idx)
    initial_ev = evaluate(ev, ev_idx) if ev is not None else None
    best, best_state, history = initial, {k: v.clone() for k, v in model.state_dict().items()}, []
    wide = max(math.radians(settings.widen_deg), train.angular_radius)
    every = max(1, settings.steps // 10)
    for step in range(settings.steps):
        a = min(1.0, step / max(1.0, settings.anneal * settings.steps))
        radius = wide + (train.angular_radius - wide) * a
        idx = rng.choice(len(train.positions), min(settings.frames_per_step, len(train.positions)), replace=False)
        verts = np.sort(rng.choice(V, nv, replace=False))
        err = _predict(model, train, idx, radius, verts) - torch.from_numpy(train.visibility[idx][:, verts])
        if cosine:
            err = err * torch.from_numpy(shading_weight(train.normals[idx][:, verts], train.directions[idx]))
        loss = torch.mean(err ** 2)
        opt.zero_grad()
        loss.backward()
        opt.step()
        if (step + 1) % every == 0 or step + 1 == settings.steps:
            e = evaluate(val, val_idx)
            history.append({"step": step + 1, "loss": float(loss.detach()), **e})
            if a >= 1.0 and e[key] < best[key]:
                best, best_state = e, {k: v.clone() for k, v in model.state_dict().items()}
        if progress is not None:
            progress.advance()
    model.load_state_dict(best_state)
    if not np.isfinite(best[key]):
        raise PrtError("peak blockers: the fit diverged (non-finite error)")
    scored = evaluate(ev, ev_idx) if ev is not None else best
    metrics = {"blockers": settings.blockers, "spheres": int(model.bone.shape[0]),
               "train_frames": int(len(train.positions)), "validation_frames": int(len(val_idx)),
               "eval_frames": int(len(ev_idx) if ev_idx is not None else len(val_idx)),
               "eval_split": "heldout" if ev is not None else "validation",
               "angular_radius_deg": math.degrees(train.angular_radius),
               "initial": initial_ev if initial_ev is not None else initial, "learned": scored, "validation": best,
               "history": history, "fit_s": time.perf_counter() - t0, "settings": settings.__dict__}
    return model, metrics

"""``runs/NAME/report/``: metrics (``results.json``), figures, a shaded comparison image and an
index (``index.md`` and ``index.html``) that shows them."""

from __future__ import annotations

import html
import json
from pathlib import Path
from typing import Any

import numpy as np

from prt_torch.eval.evaluate import Evaluation
from prt_torch.metrics import per_frame_rel_err, vis_rel_err
from prt_torch.eval.plots import plot_error_vs_alpha, plot_error_vs_variance, plot_per_frame_error, plot_spectra
from prt_torch.eval.shading import shade
from prt_torch.fit.data import dataset_info, load_split
from prt_torch.fit.ridge import ridge_path
from prt_torch.io import atomic_write_json, atomic_write_text
from prt_torch.models import load_metadata
from prt_torch.reduce import PCA, ClusterPCA
from prt_torch.models.storage import storage_markdown

VARIANCES = [0.8, 0.9, 0.95, 0.99, 0.999]
METRICS = ["vis_rel_err", "transfer_rel_err", "psnr_diffuse", "psnr_glossy", "rmse_diffuse", "rmse_glossy", "jitter"]


def _linear_predict(x_tr: np.ndarray, z_tr: np.ndarray, x_te: np.ndarray, alphas: np.ndarray) -> np.ndarray:
    w, b = ridge_path(x_tr, z_tr, alphas)
    return np.einsum("np,apgk->angk", x_te, w) + b[:, None]


def ablations(ev: Evaluation, meta: dict[str, Any], progress: Any = None) -> dict[str, Any]:
    """Spectra, error vs retained output variance and vs alpha for the linear model (closed form)."""
    dataset = Path(ev.results["dataset"])
    info = dataset_info(dataset)
    tcfg = meta["train_config"]
    train = load_split(dataset, "train", max_frames=400)
    inp = PCA.fit(train.pose, variance=tcfg["input_variance"], whiten=tcfg["whiten_inputs"])
    x_tr = inp.reduce(train.pose)
    test = ev.splits.get("heldout") or ev.splits["train"]
    x_te = inp.reduce(test.pose)
    out = ClusterPCA.fit(train.visibility, info.cluster, variance=max(VARIANCES))
    lin_alpha = float(np.median(meta["fit"].get("linear", {}).get("alpha", [1.0])))
    res: dict[str, Any] = {"input_explained": inp.explained, "input_k": inp.n_components,
                           "output_explained": [p.explained for p in out.pcas], "variances": VARIANCES}
    floor, lin = [], []
    for v in VARIANCES:
        o = out.truncated(v)
        floor.append(vis_rel_err(o.expand(o.reduce(test.visibility)), test.visibility))
        zp = _linear_predict(x_tr, o.reduce(train.visibility), x_te, np.array([lin_alpha]))[0]
        lin.append(vis_rel_err(o.expand(zp), test.visibility))
    res["error_vs_variance"] = {"PCA reconstruction floor": floor, f"linear (alpha {lin_alpha:.3g})": lin}
    o = out.truncated(tcfg["output_variance"])
    alphas = np.concatenate([[0.0], np.logspace(-4, 5, 10)])
    z_tr = o.reduce(train.visibility)
    ptr = _linear_predict(x_tr, z_tr, x_tr, alphas)
    pte = _linear_predict(x_tr, z_tr, x_te, alphas)
    res["alphas"] = alphas
    res["alpha_train"] = np.array([vis_rel_err(o.expand(p), train.visibility) for p in ptr])
    res["alpha_test"] = np.array([vis_rel_err(o.expand(p), test.visibility) for p in pte])
    res["alpha_chosen"] = lin_alpha
    return res


def write_report(ev: Evaluation, run_dir: str | Path, progress: Any = None) -> Path:
    """Write figures, image, ``results.json`` and the index into ``run_dir/report``; returns the index path."""
    run_dir = Path(run_dir)
    rep = run_dir / "report"
    rep.mkdir(parents=True, exist_ok=True)
    meta = load_metadata(run_dir)
    figs: dict[str, str] = {}
    abl = ablations(ev, meta, progress)
    plot_spectra(abl["input_explained"], abl["output_explained"], abl["input_k"], rep / "spectra.png")
    figs["PCA eigen-spectra of inputs and outputs (seed 000 Fig. 4)"] = "spectra.png"
    plot_error_vs_variance(abl["variances"], abl["error_vs_variance"], rep / "error_vs_variance.png")
    figs["Held-out error vs retained output variance (seed 003 Fig. 5)"] = "error_vs_variance.png"
    plot_error_vs_alpha(abl["alphas"], abl["alpha_train"], abl["alpha_test"], abl["alpha_chosen"],
                        rep / "error_vs_alpha.png")
    figs["Train and held-out error vs alpha, linear model (seed 000 Fig. 3)"] = "error_vs_alpha.png"
    split = "heldout" if "heldout" in ev.splits else "train"
    sp = ev.splits[split]
    per_frame = {k: per_frame_rel_err(p, sp.visibility) for k, p in ev.predictions[split].items()}
    plot_per_frame_error(per_frame, rep / "per_frame_error.png")
    figs[f"Per-model visibility error on {split} frames (seed 003 Fig. 7)"] = "per_frame_error.png"
    ev.results["ablations"] = {
        "error_vs_variance": {"variances": abl["variances"], **abl["error_vs_variance"]},
        "error_vs_alpha": {"alphas": abl["alphas"].tolist(), "train": abl["alpha_train"].tolist(),
                           "heldout": abl["alpha_test"].tolist()},
        "input_components": abl["input_k"],
    }
    info = dataset_info(Path(ev.results["dataset"]))
    image_note = ""
    if len(info.faces) and "positions" in sp.extra:
        from prt_torch.eval.render import render_panels

        f = int(np.argmax(per_frame["noshadow"])) if "noshadow" in per_frame else 0
        light = next(iter(ev.lights))
        a = ev.shading[split][f"{light}/diffuse"][f:f + 1]
        panels = {"ray-traced truth": shade(sp.visibility[f:f + 1], a)[0]}
        for k, p in ev.predictions[split].items():
            panels["no shadowing" if k == "noshadow" else k] = shade(p[f:f + 1], a)[0]
        render_panels(sp.extra["positions"][f], info.faces, panels, rep / "frame.png")
        figs[f"{split} frame {f} under '{light}', diffuse: truth | models | no shadowing (seed 000 Fig. 5)"] = \
            "frame.png"
    else:
        image_note = "(no faces in the dataset: shaded image skipped)"
    atomic_write_json(rep / "results.json", ev.results)
    md = _markdown(ev.results, figs, image_note)
    atomic_write_text(rep / "index.md", md)
    atomic_write_text(rep / "index.html", _html(md, figs))
    return rep / "index.md"


def _markdown(r: dict[str, Any], figs: dict[str, str], note: str) -> str:
    lines = [f"# Evaluation of `{r['run']}`", "", f"Dataset: `{r['dataset']}`; lights: {', '.join(r['lights'])}; "
             f"RPOs: diffuse = {r['rpos']['diffuse']}, glossy = {r['rpos']['glossy']}.", ""]
    lines += ["## Errors", "", "| model | split | " + " | ".join(METRICS) + " |",
              "| --- | --- | " + " | ".join("---:" for _ in METRICS) + " |"]
    for kind, splits in r["models"].items():
        for split, m in splits.items():
            lines.append(f"| {kind} | {split} | " + " | ".join(f"{m.get(k, float('nan')):.4g}" for k in METRICS) + " |")
    if r.get("targets"):
        t = r["targets"]
        lines += ["", f"Targets (held-out): MLP/linear error {t['mlp_over_linear']:.3f} (<= 0.7: "
                  f"{t['mlp_over_linear_ok']}), diffuse PSNR {t['psnr_diffuse']:.2f} dB (>= 40: "
                  f"{t['psnr_diffuse_ok']}), glossy PSNR {t['psnr_glossy']:.2f} dB (>= 35: {t['psnr_glossy_ok']})."]
    lines += ["", "## Storage (seed 000 Table 1)", "", storage_markdown(r["storage"]),
              "PTD: percent of the training visibility data; PSM: percent of one mesh's visibility. "
              "'stored' counts every array in the state dict (padding, int32 gather index); 'packed' only the "
              "real float32 numbers.", "", "## Fit", ""]
    for kind, f in r.get("fit", {}).items():
        a = f.get("alpha")
        lines.append(f"- {kind}: {f.get('fit_s', 0):.2f} s; alpha per cluster median "
                     f"{np.median(a) if a else float('nan'):.3g}" +
                     (f"; neurons per cluster median {np.median(f['neurons']):.0f}" if f.get("neurons") else ""))
    lines += ["", "## Figures", ""]
    for cap, fn in figs.items():
        lines += [f"### {cap}", "", f"![{cap}]({fn})", ""]
    if note:
        lines.append(note)
    return "\n".join(lines) + "\n"


def _html(md: str, figs: dict[str, str]) -> str:
    body = html.escape(md)
    imgs = "".join(f"<h3>{html.escape(c)}</h3><img src='{html.escape(f)}' style='max-width:100%'>" for c, f in
                   figs.items())
    return f"<!doctype html><html><head><meta charset='utf-8'><title>prt eval</title></head><body><pre>{body}</pre>" \
           f"{imgs}</body></html>\n"


def json_summary(results: dict[str, Any]) -> dict[str, Any]:
    """The ``prt eval --json`` object: ``models.<kind>.<split>.<metric>`` and ``storage.<kind>``."""
    out = {"models": {}, "storage": {}, "targets": results.get("targets", {})}
    for kind, splits in results["models"].items():
        out["models"][kind] = {s: {k: v for k, v in m.items()} for s, m in splits.items()}
    for kind, s in results["storage"].items():
        out["storage"][kind] = dict(s)
    return json.loads(json.dumps(out, default=float))


__all__ = ["json_summary", "write_report"]

"""The run's report directory (:attr:`prt_torch.rundir.RunDir.report_dir`): metrics (``results.json``,
schema in :mod:`prt_torch.eval.evaluate`), figures, a shaded comparison image and an index
(``index.md`` and ``index.html``) that shows them."""

from __future__ import annotations

import html
import json
from pathlib import Path
from typing import Any

import numpy as np

from prt_torch.eval.evaluate import UNSHADOWED, Evaluation
from prt_torch.eval.plots import plot_error_vs_alpha, plot_error_vs_variance, plot_per_frame_error, plot_spectra
from prt_torch.fit.ridge import ridge_path
from prt_torch.io import atomic_write_json, atomic_write_text
from prt_torch.metrics import per_frame_rel_err, vis_rel_err
from prt_torch.models.storage import storage_markdown
from prt_torch.reduce import PCA, ClusterPCA
from prt_torch.rundir import RunDir
from prt_torch.scoring.strips import abs_diff_image, image_strip, write_png

VARIANCES = [0.8, 0.9, 0.95, 0.99, 0.999]
METRICS = ["vis_rel_err", "transfer_rel_err", "psnr_diffuse", "psnr_glossy", "rmse_diffuse", "rmse_glossy", "jitter"]
#: figures inside the report directory (its index files and results are named by RunDir)
SPECTRA, ERR_VS_VAR, ERR_VS_ALPHA, PER_FRAME, FRAME_PNG = (
    "spectra.png", "error_vs_variance.png", "error_vs_alpha.png", "per_frame_error.png", "frame.png")


def _linear_predict(x_tr: np.ndarray, z_tr: np.ndarray, x_te: np.ndarray, alphas: np.ndarray) -> np.ndarray:
    w, b = ridge_path(x_tr, z_tr, alphas)
    return np.einsum("np,apgk->angk", x_te, w) + b[:, None]


def ablations(ev: Evaluation, meta: dict[str, Any]) -> dict[str, Any]:
    """Spectra, error vs retained output variance and vs alpha for the linear model (closed form)."""
    ds = ev.dataset
    assert ds is not None
    tcfg = meta["train_config"]
    train = ds.split("train", max_frames=400)
    inp = PCA.fit(train.pose, variance=tcfg["input_variance"], whiten=tcfg["whiten_inputs"],
                  max_components=tcfg.get("input_max_components"))
    x_tr = inp.reduce(train.pose)
    test = ev.splits.get("heldout") or ev.splits["train"]
    x_te = inp.reduce(test.pose)
    out = ClusterPCA.fit(train.visibility, ds.cluster, variance=max(VARIANCES))
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
    o = out.truncated(tcfg["output_variance"], tcfg.get("output_max_components"))
    alphas = np.concatenate([[0.0], np.logspace(-4, 5, 10)])
    z_tr = o.reduce(train.visibility)
    ptr = _linear_predict(x_tr, z_tr, x_tr, alphas)
    pte = _linear_predict(x_tr, z_tr, x_te, alphas)
    res["alphas"] = alphas
    res["alpha_train"] = np.array([vis_rel_err(o.expand(p), train.visibility) for p in ptr])
    res["alpha_test"] = np.array([vis_rel_err(o.expand(p), test.visibility) for p in pte])
    res["alpha_chosen"] = lin_alpha
    return res


def write_results(ev: Evaluation, run_dir: str | Path | RunDir) -> Path:
    """Only ``results.json`` (``prt eval --no-report``)."""
    run = RunDir.of(run_dir)
    run.report_dir.mkdir(parents=True, exist_ok=True)
    atomic_write_json(run.report_json, ev.results)
    return run.report_json


def write_report(ev: Evaluation, run_dir: str | Path | RunDir) -> Path:
    """Write figures, image, ``results.json`` and the index into the report directory; returns the index path."""
    run = RunDir.of(run_dir)
    rep = run.report_dir
    rep.mkdir(parents=True, exist_ok=True)
    meta = run.model_meta()
    figs: dict[str, str] = {}
    abl = ablations(ev, meta)
    plot_spectra(abl["input_explained"], abl["output_explained"], abl["input_k"], rep / SPECTRA)
    figs["PCA eigen-spectra of inputs and outputs (seed 000 Fig. 4)"] = SPECTRA
    plot_error_vs_variance(abl["variances"], abl["error_vs_variance"], rep / ERR_VS_VAR)
    figs["Held-out error vs retained output variance (seed 003 Fig. 5)"] = ERR_VS_VAR
    plot_error_vs_alpha(abl["alphas"], abl["alpha_train"], abl["alpha_test"], abl["alpha_chosen"], rep / ERR_VS_ALPHA)
    figs["Train and held-out error vs alpha, linear model (seed 000 Fig. 3)"] = ERR_VS_ALPHA
    split = "heldout" if "heldout" in ev.splits else "train"
    sp = ev.splits[split]
    per_frame = {k: per_frame_rel_err(p, sp.visibility) for k, p in ev.predictions[split].items()}
    plot_per_frame_error(per_frame, rep / PER_FRAME)
    figs[f"Per-model visibility error on {split} frames (seed 003 Fig. 7)"] = PER_FRAME
    ev.results["ablations"] = {
        "error_vs_variance": {"variances": abl["variances"], **abl["error_vs_variance"]},
        "error_vs_alpha": {"alphas": abl["alphas"].tolist(), "train": abl["alpha_train"].tolist(),
                           "heldout": abl["alpha_test"].tolist()},
        "input_components": abl["input_k"],
    }
    image_note = ""
    if split in ev.report_frame:
        f, fi = ev.report_frame[split]
        names = ["truth"] + [k for k in fi.images if k not in ("truth", UNSHADOWED)] + \
            ([UNSHADOWED] if UNSHADOWED in fi.images else [])
        labels = ["ray-traced truth" if n == "truth" else n for n in names]
        diffs = [None] + [abs_diff_image(fi.images[n], fi.images["truth"]) for n in names[1:]]
        dlabels = [""] + [f"4x |{n} - truth|" for n in names[1:]]
        write_png(rep / FRAME_PNG, image_strip([fi.images[n] for n in names], labels, diffs, dlabels))
        figs[f"{split} frame {f} (largest unshadowed error) under the player's sky, lambert, lobes path, the "
             "player's camera and one tone map from the truth: truth | models | unshadowed; row 2: 4x |image "
             "difference| (seed 000 Fig. 5)"] = FRAME_PNG
    else:
        image_note = "(no faces or no character in the dataset: shaded image skipped)"
    atomic_write_json(run.report_json, ev.results)
    md = _markdown(ev.results, figs, image_note)
    atomic_write_text(run.report_index_md, md)
    atomic_write_text(run.report_index_html, _html(md, figs))
    return run.report_index_md


def _fmt(x: Any, spec: str = ".4g") -> str:
    if x is None:
        return "-"
    return "inf" if x == float("inf") else format(x, spec)


def shading_markdown(r: dict[str, Any], split: str) -> list[str]:
    """Rows ``model | light | brdf | exact: rel RMSE, vertex PSNR, image PSNR | lobes: ...`` of one split."""
    lines = ["| model | light | BRDF | exact rel. RMSE | exact PSNR vertex | exact PSNR image | lobes rel. RMSE | "
             "lobes PSNR vertex | lobes PSNR image |", "| --- | --- | --- |" + " ---: |" * 6]
    for kind, splits in r["models"].items():
        sh = splits.get(split, {}).get("shading", {})
        for light, brdfs in sh.items():
            for brdf, paths in brdfs.items():
                cells = []
                for p in ("exact", "lobes"):
                    m = paths.get(p, {})
                    cells += [_fmt(m.get("radiance_rel_rmse")), _fmt(m.get("psnr_vertex"), ".2f"),
                              _fmt(m.get("psnr_image"), ".2f")]
                lines.append(f"| {kind} | {light} | {brdf} | " + " | ".join(cells) + " |")
    return lines


def _markdown(r: dict[str, Any], figs: dict[str, str], note: str) -> str:
    frames = ", ".join(f"{s} {n} frames ({r['image_frames'].get(s, 0)} rendered)" for s, n in r["frames"].items())
    lights = ", ".join(f"{n} ({v['source']}, ZH fit rel. error {v['zh_rel_error']:.3f})"
                       for n, v in r["lights"].items())
    lines = [f"# Evaluation of `{r['run']}`", "", f"Dataset: `{r['dataset']}`; {frames}"
             f"{' (training split subsampled)' if r.get('train_subsampled') else ''}.", "",
             f"Shipping path: RPOs {', '.join(r['brdfs'])} (the catalogue `prt export` ships) through `shade_rpo`; "
             f"lights: {lights}. Lighting paths: `exact` = the player's windowed SH rotated exactly into the "
             "vertex frames, `lobes` = the player's 3 ZH lobes fitted to that SH. Flat PSNR columns: image PSNR "
             "(character pixels, the player's camera and tone map) under the player's sky, lobes path.", ""]
    lines += ["## Errors", "", "| model | split | " + " | ".join(METRICS) + " |",
              "| --- | --- | " + " | ".join("---:" for _ in METRICS) + " |"]
    for kind, splits in r["models"].items():
        for split, m in splits.items():
            lines.append(f"| {kind} | {split} | " + " | ".join(_fmt(m.get(k)) for k in METRICS) + " |")
    if r.get("targets"):
        t = r["targets"]
        lines += ["", f"Targets (held-out): MLP/linear error {t['mlp_over_linear']:.3f} (<= 0.7: "
                  f"{t['mlp_over_linear_ok']}), diffuse image PSNR {_fmt(t['psnr_diffuse'], '.2f')} dB (>= 40: "
                  f"{t['psnr_diffuse_ok']}), glossy image PSNR {_fmt(t['psnr_glossy'], '.2f')} dB (>= 35: "
                  f"{t['psnr_glossy_ok']})."]
    for split in r["frames"]:
        lines += ["", f"## Shading, {split} ({r['frames'][split]} frames, image PSNR on "
                  f"{r['image_frames'].get(split, 0)})", ""] + shading_markdown(r, split)
        lf = r.get("lobe_fit", {}).get(split, {})
        if lf:
            lines += ["", f"Lobe fit alone ({split}: truth shaded by `lobes` vs by `exact`): " + "; ".join(
                f"{ln}/{bn} rel. RMSE {_fmt(m['radiance_rel_rmse'])}, image PSNR {_fmt(m['psnr_image'], '.2f')} dB"
                for ln, b in lf.items() for bn, m in b.items()) + "."]
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
    """The ``prt eval --json`` object: the results (schema in :mod:`prt_torch.eval.evaluate`) without the
    ablation curves, as plain JSON (numpy numbers converted)."""
    out = {k: v for k, v in results.items() if k != "ablations"}
    return json.loads(json.dumps(out, default=float))


__all__ = ["json_summary", "write_report", "write_results"]

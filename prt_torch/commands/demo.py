"""``prt demo``: the whole job on the built-in character, end to end, into ``runs/demo/``.

Steps (each reused when already done for the same inputs): bake the training and held-out clips
(resumable), fit the models, export to ONNX, play the held-out clip into an MP4 with onnxruntime,
and write a side-by-side PNG (ray-traced truth | model | unshadowed) and the metrics.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import time
from pathlib import Path
from typing import Any

import numpy as np

HELP = "Run everything on the built-in character (bake, fit, export, play, compare) into runs/demo/."

STATE_FILE = "demo_state.json"


def default_config() -> Path:
    """``configs/demo.yaml`` next to the package (a source checkout)."""
    return Path(__file__).resolve().parents[2] / "configs" / "demo.yaml"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--config", default=None, help="run config (default: configs/demo.yaml)")
    parser.add_argument("--run-dir", default=None, help="output directory (default: runs/<name> of the config)")
    parser.add_argument("--env", default=None, help="HDR environment map for the video and PNG (default: procedural "
                                                    "sun and sky)")
    parser.add_argument("--brdf", default="phong", help="BRDF of the video and PNG (default: phong)")
    parser.add_argument("--frames", type=int, default=None, help="play at most this many held-out frames")
    parser.add_argument("--size", default="640x400", help="image size HxW (default 640x400)")
    parser.add_argument("--force", action="store_true", help="redo fit and export even if up to date")


def _key(obj: Any) -> str:
    return hashlib.sha256(json.dumps(obj, sort_keys=True, default=str).encode()).hexdigest()


def _dataset_key(path: Path) -> dict[str, Any]:
    import zarr

    g = zarr.open_group(str(path), mode="r")
    a = dict(g.attrs)
    return {"fingerprint": a.get("frames_fingerprint"), "character_hash": a.get("character_hash"),
            "bake": a.get("bake"), "done": int(np.asarray(g["done"][:]).sum())}


def run(args: argparse.Namespace) -> int:
    from rich.console import Console

    from prt_torch.bake.runner import bake
    from prt_torch.config import load_config
    from prt_torch.errors import PrtError
    from prt_torch.export.run import export_run
    from prt_torch.fit.train import train_dataset
    from prt_torch.io import atomic_write_json

    console = Console(stderr=True)
    t_all = time.perf_counter()
    cfg_path = Path(args.config) if args.config else default_config()
    cfg = load_config(cfg_path)
    if args.run_dir:
        cfg.run_dir = Path(args.run_dir)
    run_dir = Path(cfg.out_dir)
    run_dir.mkdir(parents=True, exist_ok=True)
    try:
        h, w = (int(x) for x in args.size.lower().split("x"))
    except ValueError:
        raise PrtError(f"bad --size {args.size!r}: expected HxW, e.g. 480x640") from None
    state_path = run_dir / STATE_FILE
    state: dict[str, Any] = json.loads(state_path.read_text()) if state_path.is_file() else {}
    seconds: dict[str, float] = {}

    console.rule(f"[bold]prt demo -> {run_dir}")
    t0 = time.perf_counter()
    console.print("[bold]1/5 bake[/] (Embree ground truth; resumes finished blocks)")
    dataset = bake(cfg)
    seconds["bake"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    train_key = _key({"train": cfg.train.model_dump(mode="json"), "dataset": _dataset_key(dataset)})
    if not args.force and state.get("train_key") == train_key and (run_dir / "model.pt").is_file():
        console.print("[bold]2/5 fit[/]: up to date, reusing model.pt")
    else:
        console.print("[bold]2/5 fit[/] (PCA + ridge / per-cluster MLP, L-BFGS)")
        with console.status("fitting ..."):
            train_dataset(dataset, run_dir, cfg.train)
        state["train_key"] = train_key
        atomic_write_json(state_path, state)
    seconds["fit"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    console.print("[bold]3/5 export[/] (ONNX graphs, parity with torch on held-out poses)")
    meta = export_run(run_dir, force=args.force, console=console)
    seconds["export"] = time.perf_counter() - t0

    heldout = list(cfg.character.heldout_clips)
    if not heldout:
        raise PrtError(f"{cfg_path}: the demo needs a held-out clip (character.heldout_clips)")
    clip = heldout[0]

    from prt_torch.player import Player

    t0 = time.perf_counter()
    player = Player(run_dir, env=args.env, brdf=args.brdf, window_size=(h, w))
    try:
        console.print(f"[bold]4/5 compare[/] held-out '{clip}': truth | model | unshadowed -> "
                      f"{run_dir / 'comparison.png'}")
        comp = compare_heldout(player, dataset, clip, console)
        seconds["compare"] = time.perf_counter() - t0
        t0 = time.perf_counter()
        console.print(f"[bold]5/5 play[/] held-out clip '{clip}' with onnxruntime -> {run_dir / 'heldout.mp4'}")
        res = player.play(clip, out=run_dir / "heldout.mp4", frames=args.frames,
                          timings=run_dir / "heldout.timings.json")
        seconds["play"] = time.perf_counter() - t0
    finally:
        player.close()
    fit_metrics = json.loads((run_dir / "metrics.json").read_text()) if (run_dir / "metrics.json").is_file() else {}
    seconds["total"] = time.perf_counter() - t_all
    metrics = {
        "heldout_clip": clip, "n_vertices": meta["n_vertices"], "sh_order": meta["sh_order"],
        "model_kind": meta["model_kind"], "brdf": player.rpo.name, "lighting": player.lighting.source,
        "zh_fit_rel_error": player.lighting.rel_error,
        "onnx_parity_rel_error": {k: v["rel_error"] for k, v in meta["parity"].items()},
        "heldout": comp, "fit": fit_metrics,
        "play": {"frames": res.frames, "compute_fps": res.summary.get("compute_fps"),
                 "total_fps": res.summary.get("total_fps")},
        "seconds": seconds,
    }
    atomic_write_json(run_dir / "demo_metrics.json", metrics)
    console.print(f"held-out '{clip}': visibility rel. error model {comp['vis_rel_err_model']:.4f} vs "
                  f"unshadowed {comp['vis_rel_err_unshadowed']:.4f}; radiance rel. RMSE model "
                  f"{comp['radiance_rel_rmse_model']:.4f} vs unshadowed {comp['radiance_rel_rmse_unshadowed']:.4f}")
    console.print(f"playback: {res.summary.get('compute_fps', 0):.0f} frames/s compute path, "
                  f"{res.summary.get('total_fps', 0):.1f} frames/s with rendering + encoding")
    console.print(f"wrote {run_dir / 'heldout.mp4'}, {run_dir / 'comparison.png'}, {run_dir / 'demo_metrics.json'} "
                  f"in {seconds['total']:.0f} s")
    return 0


def compare_heldout(player: Any, dataset: Path, clip: str, console: Any = None) -> dict[str, Any]:
    """Truth vs model vs unshadowed on every baked frame of ``clip`` (ORT path), and the PNG.

    Returns metrics: visibility relative L2 errors (model and the unshadowed hemisphere vs the
    ray-traced truth) and radiance relative RMSEs under the player's lighting and BRDF.
    """
    import zarr

    from prt_torch.errors import PrtError
    from prt_torch.player.posing import PoseBatch
    from prt_torch.player.video import write_png

    g = zarr.open_group(str(dataset), mode="r")
    names = list(g.attrs["clip_names"])
    if clip not in names:
        raise PrtError(f"held-out clip {clip!r} is not in {dataset}")
    rows = np.flatnonzero((np.asarray(g["clip_id"][:]) == names.index(clip)) & np.asarray(g["done"][:]))
    if rows.size == 0:
        raise PrtError(f"no baked frames of {clip!r} in {dataset}")
    sel = (rows,)
    truth = np.asarray(g["visibility"].get_orthogonal_selection(sel), dtype=np.float32)
    pose = np.asarray(g["pose"].get_orthogonal_selection((rows, slice(None))), dtype=np.float32)
    pos = np.asarray(g["positions"].get_orthogonal_selection(sel), dtype=np.float32)
    frames = np.asarray(g["frames"].get_orthogonal_selection(sel), dtype=np.float32)
    n, v = pos.shape[:2]
    eye = player.eye
    view = eye[None, None, :] - pos
    view /= np.linalg.norm(view, axis=-1, keepdims=True)
    state = PoseBatch(np.ascontiguousarray(pos.transpose(0, 2, 1)),
                      np.ascontiguousarray(frames[:, :, 2].transpose(0, 2, 1)),
                      np.ascontiguousarray(frames.reshape(n, v, 9).transpose(0, 2, 1)),
                      np.ascontiguousarray(view.transpose(0, 2, 1), dtype=np.float32), pose)
    model = player.visibility(pose)
    hemi = np.broadcast_to(player.unshadowed, truth.shape)
    rad = {name: player.shade(state, visibility=vis) for name, vis in
           (("truth", truth), ("model", model), ("unshadowed", hemi))}

    def rel(a: np.ndarray, b: np.ndarray) -> float:
        return float(np.linalg.norm(a - b) / max(np.linalg.norm(b), 1e-12))

    # the frame with the most self-shadowing (largest truth vs unshadowed radiance gap)
    gap = np.abs(rad["truth"] - rad["unshadowed"]).mean(axis=(1, 2))
    i = int(np.argmax(gap))
    player.exposure = None
    player.colors(rad["unshadowed"][i])  # one exposure for all three panels, from the unshadowed one
    panels = []
    for name in ("truth", "model", "unshadowed"):
        img = player.render_frame(state, rad[name], index=i)
        panels.append(_label(img, {"truth": "ray-traced truth", "model": f"model ({player.bundle.meta['model_kind']})",
                                   "unshadowed": "unshadowed"}[name]))
    # second row: the fraction of light blocked at each vertex, 1 - lit / unshadowed (white = fully shadowed),
    # for the truth and the model, and their absolute difference, so self-shadowing is plain to see
    from prt_torch.player.tonemap import ToneMap

    unlit = rad["unshadowed"][i].sum(-1)
    blocked = {name: np.clip(1.0 - rad[name][i].sum(-1) / np.maximum(unlit, 1e-12), 0.0, 1.0)
               for name in ("truth", "model")}
    blocked["error"] = np.abs(blocked["model"] - blocked["truth"])
    player.exposure = ToneMap(1.0, None)  # type: ignore[arg-type]  # plain clip to [0, 1], then gamma
    row2 = []
    for name, label in (("truth", "light blocked: truth"), ("model", "light blocked: model"),
                        ("error", "|model - truth|")):
        grey = np.repeat(blocked[name][None, :, None], 3, axis=-1).astype(np.float32)
        row2.append(_label(player.render_frame(state, np.broadcast_to(grey, (n,) + grey.shape[1:]), index=i), label))
    out = player.bundle.run_dir / "comparison.png"
    write_png(out, np.concatenate([np.concatenate(panels, axis=1), np.concatenate(row2, axis=1)], axis=0))
    player.exposure = None  # the video picks its own
    shadowed = (rad["truth"].sum(-1) < 0.8 * rad["unshadowed"].sum(-1))  # where the truth says "in shadow"
    darker = rad["model"].sum(-1) < rad["unshadowed"].sum(-1)
    return {
        "frames": int(n), "comparison_row": int(rows[i]),
        "vis_rel_err_model": rel(model, truth), "vis_rel_err_unshadowed": rel(hemi, truth),
        "radiance_rel_rmse_model": rel(rad["model"], rad["truth"]),
        "radiance_rel_rmse_unshadowed": rel(rad["unshadowed"], rad["truth"]),
        "shadowed_vertex_fraction": float(shadowed.mean()),
        "model_darker_where_shadowed": float(darker[shadowed].mean()) if shadowed.any() else float("nan"),
    }


def _label(img: np.ndarray, text: str) -> np.ndarray:
    import cv2

    img = np.ascontiguousarray(img.copy())
    cv2.putText(img, text, (12, 28), cv2.FONT_HERSHEY_SIMPLEX, 0.8, (240, 240, 240), 2, cv2.LINE_AA)
    return img

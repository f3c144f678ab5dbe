"""``prt bench s001 [RUN]``: seed 001 playback ms per frame, side by side in one run.

On the run's held-out frames (the baked pose features, positions and vertex frames, batch 1), interleaved frame by
frame (the machine is shared: only side-by-side ratios and medians mean anything):

* ``s001``: :class:`prt_torch.s001.player.S001Player` (numpy) radiance for ONE BRDF (Lambert, the factored BRDF
  matrix, :mod:`prt_torch.s001.brdf_matrix`) in eq. 9's order, with its parts timed separately on the same frames:
  ``s001_weights`` (per-segment k-d tree + NRBF + eq. 7 coefficients), ``s001_rotations`` (segment rotations and
  the per-segment lighting);
* ``posespace``: the same player and data with the global neighbours;
* ``learned_mlp``: the run's learned visibility graph through onnxruntime (the ``prt compare`` method; visibility
  only, its shading is not included).

Reported: the median ms and frames/s of each, and the ratios to ``s001``.
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

HELP = "seed 001 playback ms/frame: s001 (and its parts) vs posespace vs learned_mlp, interleaved."


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("run", nargs="?", default="runs/s001", help="run trained with train.s001 (default runs/s001)")
    parser.add_argument("--frames", type=int, default=12, help="held-out frames timed (default 12)")
    parser.add_argument("--threads", type=int, default=2, help="onnxruntime threads of learned_mlp (default 2)")
    parser.add_argument("--json", action="store_true", help="print the JSON only")


def run(args: argparse.Namespace) -> int:
    from prt_torch import limits
    from prt_torch.brdf.rpo import builtin_brdf
    from prt_torch.commands import _validate as V
    from prt_torch.compare.methods import METHODS
    from prt_torch.compare.run import heldout_frames, load_compare_run
    from prt_torch.errors import check
    from prt_torch.player.lighting import load_lighting
    from prt_torch.progress import make_console
    from prt_torch.s001.brdf_matrix import brdf_matrix, factor
    from prt_torch.s001.player import S001Player
    from prt_torch.s001.posespace import CompressedTransfer
    from prt_torch.scoring.images import player_camera

    check(1 <= args.frames <= limits.MAX_FRAMES, f"--frames must be in 1..{limits.MAX_FRAMES}, got {args.frames}")
    V.input_dir(args.run, "run")
    ctx = load_compare_run(args.run, threads=args.threads)
    check(ctx.run.s001.is_file(), f"{ctx.run.s001} not found (train with a `train.s001` section)")
    fs = heldout_frames(ctx, args.frames)
    data = CompressedTransfer.load(ctx.run.s001)
    order = int(round(data.n_coeffs**0.5))
    light = load_lighting(None, order).sh[: order * order]
    hg = {"lambert": factor(brdf_matrix(builtin_brdf("lambert"), order), 4)}
    eye = player_camera(ctx.character).eye
    players = {s: S001Player(data, s) for s in ("s001", "posespace")}  # type: ignore[arg-type]
    for p in players.values():
        p.set_shading(hg, light)
    mlp = None
    if "learned_mlp" in METHODS and METHODS["learned_mlp"].available(ctx):
        mlp = METHODS["learned_mlp"]()
        mlp.prepare(ctx, fs)
    s = players["s001"]

    def parts(f: int) -> dict[str, float]:
        t: dict[str, float] = {}
        for name, fn in (("s001_weights", lambda: s._weights(fs.features[f])),
                         ("s001_rotations", lambda: s.rotations(fs.frames[f])),
                         ("s001", lambda: s.radiance(fs.features[f], fs.frames[f], fs.positions[f], eye)),
                         ("posespace", lambda: players["posespace"].radiance(fs.features[f], fs.frames[f],
                                                                             fs.positions[f], eye))):
            t0 = time.perf_counter()
            fn()
            t[name] = time.perf_counter() - t0
        if mlp is not None:
            t0 = time.perf_counter()
            mlp.visibility(fs.batch(f))
            t["learned_mlp"] = time.perf_counter() - t0
        return t

    parts(0)  # warm-up
    secs: dict[str, list[float]] = {}
    for f in range(fs.n_frames):
        for k, v in parts(f).items():
            secs.setdefault(k, []).append(v)
    med = {k: float(np.median(v) * 1e3) for k, v in secs.items()}
    out = {"run": str(ctx.run.path), "frames": fs.n_frames, "n_vertices": ctx.n_vertices,
           "n_clusters": data.meta.get("n_clusters"), "n_poses": data.meta.get("n_poses"),
           "ms_per_frame": med, "fps": {k: 1e3 / v for k, v in med.items()},
           "ratio_to_s001": {k: v / med["s001"] for k, v in med.items()}}
    if args.json:
        print(json.dumps(out, indent=2, sort_keys=True))
        return 0
    con = make_console()
    con.print(f"{out['frames']} held-out frames, {out['n_vertices']} vertices, {out['n_clusters']} PCA clusters")
    for k, v in med.items():
        con.print(f"{k:16s} {v:9.2f} ms  {1e3 / v:8.1f} frames/s  x{out['ratio_to_s001'][k]:.2f} of s001")
    return 0

"""``prt bench shexp [RUN]``: SHEXP sphere-blocker visibility ms per frame, side by side in one run.

On the run's held-out frames (the baked positions and vertex frames ``prt compare`` uses, batch 1), interleaved
frame by frame (the machine is shared: only side-by-side ratios and medians mean anything):

* ``ort``: the SHEXP graph of THIS code (:func:`prt_torch.shexp.graph.export_shexp`, exported to a
  temporary file) through onnxruntime (:class:`prt_torch.scene.occluders.ShexpGraph`, no culling), the
  character's vertices under its own spheres;
* ``shipped``: the run's own ``shexp.onnx`` (as written by the ``prt export`` that made it: an older export
  runs the older graph) -- the before/after of a code change without keeping the old code;
* ``baseline`` (``--baseline FILE``): any other SHEXP graph file, same inputs (and ``baseline_floor``,
  ``baseline_other_character``: the two scene cases below with it);
* ``torch``: :func:`prt_torch.shexp.shexp_visibility` (eager, chunked, ONE torch thread: with 2 OpenMP threads on
  a loaded shared machine its barriers make calls vary 30 ms - 8 s, and its spinning threads slow the others);
* ``learned_mlp``: the run's learned visibility graph (the ``prt compare`` method, its shipping path);
* ``floor``: the 64 x 64 floor (4225 receivers) under the character's spheres, culled like the scene player;
* ``other_character``: the character's vertices under a second character's spheres (the same spheres moved by
  ``(-0.9, 0.9, 0)`` as in ``configs/scene2.yaml``), culled like the scene player.

Reported: the median ms of each and its ratio to ``learned_mlp``; ``agreement``: max |ort - shipped| / max |ort|
(the numerics of the two graphs on the same frames).
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

HELP = "SHEXP ms/frame: this code's graph vs the run's shipped graph, torch, learned_mlp, the floor, 2 characters."


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("run", nargs="?", default="runs/demo", help="exported run (default runs/demo)")
    parser.add_argument("--frames", type=int, default=12, help="held-out frames timed (default 12)")
    parser.add_argument("--threads", type=int, default=2, help="onnxruntime threads (default 2)")
    parser.add_argument("--baseline", default=None, help="another SHEXP graph file to time on the same inputs")
    parser.add_argument("--json", action="store_true", help="print the JSON only")


def run(args: argparse.Namespace) -> int:
    import torch

    from prt_torch import limits
    from prt_torch.blockers import SphereSet, pose_spheres
    from prt_torch.commands import _validate as V
    from prt_torch.compare.methods import METHODS
    from prt_torch.compare.run import heldout_frames, load_compare_run
    from prt_torch.errors import check
    from prt_torch.progress import make_console
    from prt_torch.scene.ground import make_ground
    from prt_torch.scene.occluders import ShexpGraph
    from prt_torch.shexp import shexp_visibility
    from prt_torch.shexp.compare import frame_skins
    from prt_torch.shexp.graph import export_shexp

    limits.check_int(args.frames, "--frames", 1, 10_000)
    limits.check_int(args.threads, "--threads", 1, limits.MAX_THREADS)
    V.input_dir(args.run, "run directory")
    if args.baseline is not None:
        V.input_file(args.baseline, "--baseline")
    torch.set_num_threads(1)  # module doc
    ctx = load_compare_run(args.run, threads=args.threads)
    rd = ctx.run
    check(rd.blockers_path.is_file(), f"{rd.path}: no {rd.relative(rd.blockers_path)}: run `prt export {rd.path}`")
    fs = heldout_frames(ctx, args.frames)
    spheres = SphereSet.load(rd.blockers_path)
    centers = pose_spheres(spheres, frame_skins(ctx, fs)).astype(np.float32)  # (F, S, 3)
    radii = np.broadcast_to(spheres.radius.astype(np.float32), centers.shape[:2]).copy()
    order = ctx.order
    console = make_console(stderr=True)
    with tempfile.TemporaryDirectory(prefix="prt_bench_shexp_") as tmp:
        path = export_shexp(Path(tmp) / rd.shexp_path.name, order)
        graphs = {"ort": ShexpGraph(path, order, threads=args.threads)}
        if rd.shexp_path.is_file():
            graphs["shipped"] = ShexpGraph(rd.shexp_path, order, threads=args.threads)
        if args.baseline is not None:
            graphs["baseline"] = ShexpGraph(args.baseline, order, threads=args.threads)
        mlp = METHODS["learned_mlp"]()
        mlp.prepare(ctx, fs)
        pos = fs.positions
        lo, hi = pos.reshape(-1, 3).min(0), pos.reshape(-1, 3).max(0)
        ground = make_ground(0.5 * (lo[:2] + hi[:2]), float(2.5 * max(hi[:2] - lo[:2]) + 1.0), float(lo[2]), 64)
        g_pts, g_frm = ground.vertices[None], np.ascontiguousarray(ground.frames((1,)))
        shift = np.array([-0.9, 0.9, 0.0], np.float32)

        def inputs(f: int) -> tuple[np.ndarray, ...]:
            return (pos[f:f + 1], np.ascontiguousarray(fs.frames[f:f + 1]), centers[f:f + 1], radii[f:f + 1])

        calls: dict[str, Any] = {name: (lambda f, g=g: g(*inputs(f), cull=0.0)) for name, g in graphs.items()}
        calls["torch"] = lambda f: shexp_visibility(pos[f], centers[f], radii[f], order, frames=fs.frames[f]).numpy()
        calls["learned_mlp"] = lambda f: mlp.visibility(fs.batch(f))
        for name in ("ort", "baseline"):
            if name in graphs:
                tag = "" if name == "ort" else "baseline_"
                calls[f"{tag}floor"] = lambda f, g=graphs[name]: g(g_pts, g_frm, centers[f:f + 1], radii[f:f + 1])
                calls[f"{tag}other_character"] = lambda f, g=graphs[name]: g(
                    pos[f:f + 1], np.ascontiguousarray(fs.frames[f:f + 1]), centers[f:f + 1] + shift, radii[f:f + 1])
        names = list(calls)
        secs: dict[str, list[float]] = {n: [] for n in names}
        outs: dict[str, np.ndarray] = {}
        for n in names:  # warm-up, untimed
            outs[n] = calls[n](0)
        for f in range(fs.n_frames):
            for j in range(len(names)):  # the order rotates each frame
                n = names[(f + j) % len(names)]
                t0 = time.perf_counter()
                calls[n](f)
                secs[n].append(time.perf_counter() - t0)
    ms = {n: float(np.median(s) * 1e3) for n, s in secs.items()}
    out: dict[str, Any] = {"run": str(rd.path), "frames": fs.n_frames, "threads": args.threads, "order": order,
                           "vertices": int(pos.shape[1]), "spheres": int(centers.shape[1]),
                           "floor_receivers": ground.n_vertices,
                           "ms": ms, "ratio_vs_learned_mlp": {n: ms[n] / ms["learned_mlp"] for n in names}}
    ref = np.abs(outs["ort"]).max()
    for n in ("shipped", "baseline", "torch"):
        if n in outs:
            out.setdefault("agreement", {})[n] = float(np.abs(outs[n] - outs["ort"]).max() / ref)
    if args.json:
        print(json.dumps(out, indent=1))
        return 0
    console.print(f"[bold]prt bench shexp[/] {rd.path} ({fs.n_frames} held-out frames, {out['vertices']} vertices x "
                  f"{out['spheres']} spheres, order {order}, {args.threads} threads, medians)")
    for n in names:
        agree = out.get("agreement", {}).get(n)
        console.print(f"  {n:16s} {ms[n]:8.1f} ms  ({out['ratio_vs_learned_mlp'][n]:6.1f}x learned_mlp)"
                      + ("" if agree is None else f"  max diff vs ort {agree:.2e} of max"))
    print(json.dumps(out))
    return 0

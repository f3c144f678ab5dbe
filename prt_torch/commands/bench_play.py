"""``prt bench play [RUN]``: frames/s of the run-time path, its steps, and side-by-side references.

Measured in one run on the exported run (default ``runs/demo``: built-in character ~11.7k vertices,
order 4, MLP model) with an 8-term RPO (``phong``):

* per-frame path (numpy FK + LBS + frames + pose features -> ORT -> radiance), fused graph, split
  graphs (visibility then shading) and the fused graph on a player with 1 onnxruntime thread
  (``fused_1thread``) and the ``overlap`` player (visibility on a worker thread during the posing),
  interleaved frame by frame; median over ``--frames``; the fastest is ``fps``;
  then the fused graph with spinning ORT threads (``fused_spin``, a second player) in
  alternating blocks against the non-spinning one (``fused_blocks``);
* (a) ray tracing the same frames' visibility with Embree (``prt_torch.bake.trace.trace_frame``, the
  bake's per-frame path, ``--rays`` 512 by default as in the bake config) and shading it: ``speedup_vs_raytrace``;
* (b) the model's bytes (ONNX initializers + RPO tensors) over the machine's measured copy bandwidth
  (large ``numpy.copyto``): ``bandwidth_fraction = stream time / frame time`` (1.0 = the frame costs
  no more than streaming the weights once);
* batched playback of 32 characters per call: character-frames/s;
* a floor: the shading's multiply-adds at numpy's measured float32 GEMM rate (2 threads) plus the
  stream time of (b).
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path
from typing import Any

import numpy as np

HELP = "Player frames/s (fused vs split), per-step times, speed-up vs Embree ray tracing, bandwidth bound, B=32."


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("run", nargs="?", default="runs/demo", help="exported run (default runs/demo; `prt demo`)")
    parser.add_argument("--frames", type=int, default=200, help="timed frames per mode (default 200)")
    parser.add_argument("--warmup", type=int, default=20)
    parser.add_argument("--brdf", default="phong", help="RPO of the run (default phong, 8 terms)")
    parser.add_argument("--raytrace-frames", type=int, default=3, help="frames ray-traced for the baseline")
    parser.add_argument("--rays", type=int, default=512,
                        help="rays per vertex of the ray-traced baseline (default 512, the bake config default; "
                             "0: the run's own bake n_rays)")
    parser.add_argument("--batch", type=int, default=32, help="characters per call for the batched figure")
    parser.add_argument("--threads", type=int, default=2, help="onnxruntime intra-op threads")
    parser.add_argument("--no-spinning", action="store_true",
                        help="skip the 'fused_spin' blocks (onnxruntime threads busy-waiting between calls)")
    parser.add_argument("--json", action="store_true", help="print one JSON object")


def _median_ms(v: list[float]) -> float:
    return float(np.median(v) * 1e3)


def copy_bandwidth(n_bytes: int = 1 << 28, repeats: int = 5) -> float:
    """Best-of-``repeats`` bytes/s of ``numpy.copyto`` between two ``n_bytes`` float32 buffers."""
    a = np.ones(n_bytes // 4, dtype=np.float32)
    b = np.empty_like(a)
    np.copyto(b, a)
    best = float("inf")
    for _ in range(repeats):
        t0 = time.perf_counter()
        np.copyto(b, a)
        best = min(best, time.perf_counter() - t0)
    return a.nbytes / best


def gemm_rate(n_vertices: int, n_coeffs: int, n_terms: int, threads: int, repeats: int = 25) -> float:
    """Best FLOP/s of numpy's float32 GEMM of the shading's RPO step ``(C, k*C) @ (k*C, V)`` over
    ``repeats`` calls with 1 and with ``threads`` BLAS threads (2 threads lose badly whenever the other
    core is busy, so the better of the two is the machine's usable compute rate for that step)."""
    from threadpoolctl import threadpool_limits

    rng = np.random.default_rng(0)
    a = rng.standard_normal((n_coeffs, n_terms * n_coeffs)).astype(np.float32)
    x = rng.standard_normal((n_terms * n_coeffs, n_vertices)).astype(np.float32)
    out = np.empty((n_coeffs, n_vertices), np.float32)
    best = float("inf")
    for n in sorted({1, max(1, threads)}):
        with threadpool_limits(limits=n, user_api="blas"):
            for _ in range(3):
                np.matmul(a, x, out=out)
            for _ in range(repeats):
                t0 = time.perf_counter()
                np.matmul(a, x, out=out)
                best = min(best, time.perf_counter() - t0)
    return 2.0 * a.shape[0] * a.shape[1] * n_vertices / best


def frame_floor(n_vertices: int, order: int, n_terms: int, n_lobes: int, stream_s: float,
                gemm_flops: float) -> dict[str, float]:
    """A lower bound on the model's frame time: the shading's multiply-adds at the measured GEMM rate plus
    streaming the model's bytes once (they do not overlap in the sequential graph).

    Per vertex the shading needs ``k C^2`` MACs for ``sum_b a_b M_b v`` (dense RPO), ``P C`` per lobe for
    the lobe SH (``P`` monomials of degree ``< order``), ``P k`` for the view factors and ``3 K C`` for
    the lighting dot products; everything else is elementwise.
    """
    c = order * order
    p = order * (order + 1) * (order + 2) // 6
    macs = n_vertices * (n_terms * c * c + n_terms * c + n_lobes * p * c + p * n_terms + 3 * n_lobes * c)
    shading_s = 2.0 * macs / gemm_flops
    return {"shading_gflop": 2e-9 * macs, "shading_ms": shading_s * 1e3, "stream_ms": stream_s * 1e3,
            "floor_ms": (shading_s + stream_s) * 1e3}


def run(args: argparse.Namespace) -> int:
    from rich.console import Console
    from rich.table import Table

    from prt_torch import limits
    from prt_torch.commands import _validate as V
    from prt_torch.errors import PrtError, check
    from prt_torch.export.onnx_file import initializer_bytes
    from prt_torch.player import Player
    from prt_torch.player.timing import FrameTimer

    limits.check_int(args.frames, "--frames", 5, limits.MAX_FRAMES)
    limits.check_int(args.warmup, "--warmup", 1, limits.MAX_REPEATS)
    limits.check_int(args.raytrace_frames, "--raytrace-frames", 1, limits.MAX_REPEATS)
    limits.check_int(args.rays, "--rays", 0, limits.MAX_RAYS)
    limits.check_int(args.batch, "--batch", 1, limits.MAX_BATCH)
    limits.check_int(args.threads, "--threads", 1, limits.MAX_THREADS)
    if not args.brdf.strip():
        raise PrtError("--brdf: empty name")
    V.input_dir(args.run, "run directory")
    console = Console(stderr=True)
    run_dir = Path(args.run)
    check(args.frames >= 5 and args.warmup >= 1, "--frames must be >= 5 and --warmup >= 1")
    player = Player(run_dir, brdf=args.brdf, graph="fused", threads=args.threads)
    meta = player.bundle.meta
    clips = list(player.character.clips)
    check(bool(clips), f"{run_dir}: the character has no clips")
    clip = max(clips, key=lambda c: player.character.clip(c).num_frames)
    locals_ = player.clip_locals(clip)
    n_clip = len(locals_)

    # -- per-frame path, fused vs split, interleaved frame by frame ---------------------------------
    steps: dict[str, dict[str, list[float]]] = {"fused": {"pose": [], "fused": [], "total": []},
                                                "split": {"pose": [], "visibility": [], "shading": [], "total": []}}

    def frame(pl: Player, mode: str, loc: np.ndarray) -> dict[str, float]:
        if mode == "overlap":
            timer = FrameTimer()
            pl.compute_overlapped(loc, timer)
            return {k: v[0] for k, v in timer.steps.items()}
        pl.graph = "split" if mode == "split" else "fused"
        t0 = time.perf_counter()
        state = pl.pose(loc)
        t1 = time.perf_counter()
        if mode != "split":
            pl.shade(state, checked=False)
            return {"pose": t1 - t0, "fused": time.perf_counter() - t1}
        vis = pl.visibility(state.features, checked=False)
        t2 = time.perf_counter()
        pl.shade(state, visibility=vis, checked=False)
        return {"pose": t1 - t0, "visibility": t2 - t1, "shading": time.perf_counter() - t2}

    def record(mode: str, parts: dict[str, float]) -> None:
        for k, v in parts.items():
            steps[mode][k].append(v)
        steps[mode]["total"].append(sum(parts.values()))

    # the same fused graph with ONE onnxruntime thread (no thread wake-ups per node; on a busy 2-core
    # machine the second core is often not free anyway)
    modes: dict[str, Player] = {"fused": player, "split": player}
    if args.threads != 1:
        modes["fused_1thread"] = Player(run_dir, brdf=args.brdf, graph="fused", threads=1)
        steps["fused_1thread"] = {"pose": [], "fused": [], "total": []}
    # visibility on a worker thread during the numpy posing (pays off only when the second core is free)
    modes["overlap"] = Player(run_dir, brdf=args.brdf, graph="overlap", threads=args.threads)
    steps["overlap"] = {"pose": [], "visibility": [], "shading": [], "total": []}
    with console.status(f"timing {args.frames} frames per mode on '{clip}' ..."):
        for i in range(args.warmup + args.frames):
            loc = locals_[i % n_clip:i % n_clip + 1]
            for mode, pl in modes.items():
                parts = frame(pl, mode, loc)
                if i >= args.warmup:
                    record(mode, parts)
    for pl in modes.values():
        if pl is not player:
            pl.close()
    # spinning ORT threads busy-wait between calls and would slow any mode interleaved with them: timed in
    # alternating blocks of frames against the (non-spinning) fused player instead
    if not args.no_spinning:
        spin = Player(run_dir, brdf=args.brdf, graph="fused", threads=args.threads, spinning=True)
        steps["fused_spin"] = {"pose": [], "fused": [], "total": []}
        steps["fused_blocks"] = {"pose": [], "fused": [], "total": []}
        block = max(5, args.frames // 4)
        with console.status("timing fused with spinning onnxruntime threads (alternating blocks) ..."):
            for rep in range(4):
                for mode, pl in (("fused_blocks", player), ("fused_spin", spin)):
                    for i in range(args.warmup // 2 + block):
                        j = (rep * block + i) % n_clip
                        parts = frame(pl, mode, locals_[j:j + 1])
                        if i >= args.warmup // 2:
                            record(mode, parts)
        spin.close()
    player.graph = "fused"
    med = {m: {k: _median_ms(v) for k, v in s.items()} for m, s in steps.items()}
    best_mode = min(modes, key=lambda m: med[m]["total"])  # interleaved modes (not the blocks)
    frame_s = med[best_mode]["total"] / 1e3
    fps = 1.0 / frame_s

    # -- (a) Embree ray tracing of the same frames + shading -----------------------------------
    from prt_torch.bake.embree import ray_offset
    from prt_torch.bake.trace import RaySet, trace_frame
    from prt_torch.rundir import RunDir

    run = RunDir(run_dir)
    ds_attrs = run.dataset().attrs if run.dataset_path.exists() else {}
    n_rays = int(args.rays or ds_attrs.get("n_rays") or 128)
    rel_offset = float((ds_attrs.get("bake") or {}).get("ray_offset", 1e-4))
    rays = RaySet.make(n_rays, player.order, player.bundle.n_vertices, seed=0)
    offset = ray_offset(player.character.rest_vertices, rel_offset)
    faces = player.character.faces
    rt: list[float] = []
    rt_model: list[float] = []
    with console.status(f"ray-tracing {args.raytrace_frames} frames with Embree ({n_rays} rays/vertex) ..."):
        for j in range(args.raytrace_frames):
            loc = locals_[(j * 7) % n_clip:(j * 7) % n_clip + 1]
            t0 = time.perf_counter()
            state = player.pose(loc)
            res = trace_frame(state.positions_vx3(0), state.frames_vx33()[0], faces, rays, offset)
            player.shade(state, visibility=res.visibility[None], checked=False)
            rt.append(time.perf_counter() - t0)
            t0 = time.perf_counter()
            state = player.pose(loc)
            player.shade(state, checked=False)
            rt_model.append(time.perf_counter() - t0)
    raytrace_s = float(np.median(rt))
    speedup = raytrace_s / frame_s  # vs the median model frame of the timed loop above
    speedup_paired = raytrace_s / float(np.median(rt_model))  # vs the model on the same few frames, cold

    # -- (b) bandwidth bound --------------------------------------------------------------------
    with console.status("measuring copy bandwidth and GEMM throughput ..."):
        bw = copy_bandwidth()
        gemm_flops = gemm_rate(player.bundle.n_vertices, player.order ** 2, int(player.rpo.M.shape[0]),
                               args.threads)
    if best_mode not in ("split", "overlap"):
        model_bytes = initializer_bytes(run.graph_path("fused"))
    else:
        model_bytes = initializer_bytes(run.graph_path("visibility")) + initializer_bytes(run.graph_path("shading"))
    model_bytes += player.rpo.M.nbytes + player.rpo.w.nbytes + player.lighting.coeffs.nbytes
    stream_s = model_bytes / bw
    bandwidth_fraction = stream_s / frame_s
    floor = frame_floor(player.bundle.n_vertices, player.order, int(player.rpo.M.shape[0]),
                        player.lighting.dirs.shape[0], stream_s, gemm_flops)

    # -- batched: B characters per call ----------------------------------------------------------
    b = args.batch
    idx = np.arange(b) * 3 % n_clip
    batch_locals = locals_[idx]
    bt: list[float] = []
    with console.status(f"batched playback, B={b} ..."):
        for i in range(3 + max(5, args.frames // 20)):
            t0 = time.perf_counter()
            state = player.pose(batch_locals)
            player.shade(state, checked=False)
            if i >= 3:
                bt.append(time.perf_counter() - t0)
    batch_s = float(np.median(bt))
    player.close()

    out: dict[str, Any] = {
        "run": str(run_dir), "clip": clip, "n_vertices": player.bundle.n_vertices, "sh_order": player.order,
        "model_kind": meta["model_kind"], "brdf": player.rpo.name, "brdf_terms": int(player.rpo.M.shape[0]),
        "threads": args.threads, "frames": args.frames,
        "fps": fps, "frame_ms": frame_s * 1e3, "best_graph": best_mode,
        "fps_fused": 1e3 / med["fused"]["total"], "fps_split": 1e3 / med["split"]["total"],
        "steps_ms": med,
        "raytrace_ms": raytrace_s * 1e3, "raytrace_n_rays": n_rays, "speedup_vs_raytrace": speedup,
        "speedup_vs_raytrace_paired_cold": speedup_paired,
        "copy_bandwidth_gb_s": bw / 1e9, "model_bytes": int(model_bytes), "stream_ms": stream_s * 1e3,
        "bandwidth_fraction": bandwidth_fraction,
        "batch": b, "batched_call_ms": batch_s * 1e3, "batched_character_fps": b / batch_s,
        "gemm_gflop_s": gemm_flops / 1e9, "floor": floor,
    }
    if args.json:
        print(json.dumps(out, indent=2, sort_keys=True))
        return 0
    t = Table(title=f"prt bench play: {run_dir} ({out['n_vertices']} vertices, order {out['sh_order']}, "
                    f"{out['model_kind']}, {out['brdf']} k={out['brdf_terms']}, {args.threads} ORT threads)")
    t.add_column("measure")
    t.add_column("value", justify="right")
    for m in med:
        parts = ", ".join(f"{k} {v:.3f}" for k, v in med[m].items() if k != "total")
        t.add_row(f"{m} graph: ms/frame ({parts})", f"{med[m]['total']:.3f} ms = {1e3 / med[m]['total']:.0f} fps")
    t.add_row(f"Embree ray trace ({n_rays} rays/vertex) + shading, per frame", f"{raytrace_s * 1e3:.0f} ms")
    t.add_row("speed-up of the model path over ray tracing (median frame; paired cold frames)",
              f"{speedup:.0f}x ({speedup_paired:.0f}x)")
    t.add_row(f"model bytes {model_bytes / 1e6:.2f} MB at copy bandwidth {bw / 1e9:.1f} GB/s",
              f"{stream_s * 1e3:.3f} ms")
    t.add_row("bandwidth fraction (stream time / frame time)", f"{bandwidth_fraction:.3f}")
    t.add_row(f"GEMM ({floor['shading_gflop']:.3f} GFLOP shading) at {gemm_flops / 1e9:.0f} GFLOP/s + stream "
              f"(floor, posing excluded)", f"{floor['floor_ms']:.3f} ms = {1e3 / floor['floor_ms']:.0f} fps")
    t.add_row(f"batched B={b}: per call", f"{batch_s * 1e3:.1f} ms = {b / batch_s:.0f} character-frames/s")
    Console().print(t)  # the result table on stdout (progress went to stderr)
    return 0

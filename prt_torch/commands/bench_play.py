"""``prt bench play [RUN]``: the run-time path against its roofline, measured side by side in one process.

On the exported run (default ``runs/demo``: built-in character ~11.7k vertices, order 4, MLP model) with an
8-term RPO (``phong``), everything timed interleaved frame by frame, in ``--repeats`` blocks, medians reported
(the machine is shared: only side-by-side ratios and medians mean anything):

* the per-frame path the player plays by default - ``fps``, ``roofline_fraction``, ``steps.frame``: on the CPU
  with an export that ships it, the compiled path (``posing_compiled``: FK + LBS + frames + features in two
  compiled passes; ``compiled``: the latent graph + the decode + shade pass, :mod:`prt_torch.player.compiled`),
  else the fused path; next to it the numpy posing + ONE fused ORT call (``posing``, ``fused``,
  ``frame_fused``), and the split graphs of the same frames for the per-step split (``visibility``, ``shading``);
* the visibility model at every weight precision (float32, float16, int8: exported from the run's model into a
  temporary directory), its bytes and time side by side;
* the ROOFLINE: per step the bytes that must move (weights read once, inputs read once, outputs written once) and
  the FLOPs that must run, the machine's copy bandwidth (``numpy.copyto`` of a buffer the size of the model:
  read + write traffic) and float32 GEMM rate (the shading's RPO GEMM shape, best of 1 and ``--threads`` BLAS
  threads), both measured in this process before and after the timings (the best of them is used), give the
  step's lower bound ``max(bytes / bandwidth, flops / GEMM rate)``; the frame's bound is the sum over its
  sequential steps (posing + fused); ``roofline_fraction = frame bound / measured frame time``;
* crowds: ``N`` characters (different clips, staggered) per call of every graph, ``N`` in ``--crowd``:
  character-frames/s and the crowd's bound (weights once, per-character bytes and FLOPs ``N`` times);
* Embree ray tracing of the same frames' visibility (the bake's per-frame path, ``--rays``) + shading:
  ``speedup_vs_raytrace``;
* ``--scaling``: frame time and bound against vertex count (the built-in character at densities 0.25 .. 4, ~3k ..
  47k vertices, with a synthetic model of the run's structure: its MLP, per-cluster bases of its sizes, random
  values) and against crowd size; plotted to ``--plot``.

* peak lights (issue 27; the player's default lighting, the procedural sky, has one: its sun): the whole frame with
  the peaks' term (posing + fused call + peak visibility + peak shading, :meth:`~prt_torch.player.player.Player.
  compute`) next to the same frame without it, interleaved frame by frame: ``peaks`` (``frame_ms_on`` /
  ``frame_ms_off``, ``fps_on`` / ``fps_off``, their ``ratio``, the peak visibility's and the peak shading's ms, the
  visibility's ``kind``; with learned blockers and ``fused_peaks.onnx``, ``frame_ms_fused_peaks``: the same frame
  through that one graph, graph mode ``fused_peaks``);

* the posing as an ONNX graph (:mod:`prt_torch.export.posing_graph`, exported into the temporary directory; needs
  torch) next to the numpy posing: ``posing_onnx``, ``frame_posing_onnx`` (it + the fused call, two ORT calls) and
  ``frame_chained`` (ONE ORT call: the posing graph chained into the fused graph) - a measurement, not the shipping
  path;

JSON keys (``--json``): ``fps``, ``roofline_fraction``, ``steps: {NAME: {ms, bound_ms, bytes, flops, bound_by}}``,
``peaks``, ``batched_character_fps``, ``speedup_vs_raytrace``, ``bytes_model``, ``crowd``, ``precisions``, ``machine``
(``copy_bandwidth_gb_s``, ``gemm_gflop_s``), ``scaling`` (with ``--scaling``).
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from prt_torch.commands.roofline import bound, compiled_costs, copy_bandwidth, gemm_rate, step_costs

HELP = ("Player frames/s against a roofline measured in the same run (per step bytes/FLOPs), precisions, crowds, "
        "speed-up vs Embree; --scaling plots cost vs vertex count and crowd size.")

#: built-in character densities of ``--scaling`` (~3k, 6k, 12k, 24k, 47k vertices)
SCALING_DENSITIES = (0.25, 0.5, 1.0, 2.0, 4.0)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("run", nargs="?", default="runs/demo", help="exported run (default runs/demo; `prt demo`)")
    parser.add_argument("--frames", type=int, default=100, help="timed frames per repeat (default 100)")
    parser.add_argument("--repeats", type=int, default=3, help="interleaved blocks; medians over all (default 3)")
    parser.add_argument("--warmup", type=int, default=10)
    parser.add_argument("--brdf", default="phong", help="RPO of the run (default phong, 8 terms)")
    parser.add_argument("--raytrace-frames", type=int, default=2, help="frames ray-traced for the baseline")
    parser.add_argument("--rays", type=int, default=512,
                        help="rays per vertex of the ray-traced baseline (default 512, the bake config default; "
                             "0: the run's own bake n_rays)")
    parser.add_argument("--crowd", default="1,8,32,128", help="crowd sizes, comma-separated (default 1,8,32,128)")
    parser.add_argument("--batch", type=int, default=32, help="the crowd size reported as batched_character_fps")
    parser.add_argument("--crowd-chunk", type=int, default=4,
                        help="also time crowds in fused calls of this many characters, alongside one call per "
                             "crowd (0: skip)")
    parser.add_argument("--precisions", default="fp32,fp16,int8",
                        help="visibility-model precisions timed side by side ('' to skip; needs torch)")
    parser.add_argument("--threads", type=int, default=2, help="onnxruntime intra-op threads")
    parser.add_argument("--device", default="cpu", choices=["cpu", "cuda"],
                        help="onnxruntime device (cuda: onnxruntime-gpu and a GPU)")
    parser.add_argument("--scaling", action="store_true", help="also time vertex counts ~3k..47k and plot")
    parser.add_argument("--plot", default="docs/play_scaling.png", help="scaling figure (PNG) with --scaling")
    parser.add_argument("--peaks", default="auto", help="peak lights of the timed frames with peaks: auto (the "
                                                        "sky's sun), or K in 1..4 (default auto; 0 skips them)")
    parser.add_argument("--peak-visibility", default=None,
                        help="the peaks' visibility: exact, spheres or learned (default: the player's, learned when "
                             "the run has its peak blockers)")
    parser.add_argument("--json", action="store_true", help="print one JSON object")


def _median_ms(v: list[float]) -> float:
    return float(np.median(v) * 1e3) if v else float("nan")


def _parse_sizes(text: str, name: str, hi: int) -> list[int]:
    from prt_torch.errors import PrtError

    try:
        sizes = sorted({int(x) for x in text.split(",") if x.strip()})
    except ValueError:
        raise PrtError(f"{name}: expected comma-separated integers, got {text!r}") from None
    if not sizes or sizes[0] < 1 or sizes[-1] > hi:
        raise PrtError(f"{name}: sizes must be 1..{hi}, got {text!r}")
    return sizes


def run(args: argparse.Namespace) -> int:
    from prt_torch.cloth.player import is_deformable_export

    if is_deformable_export(args.run):  # a cloth run: positions -> frames + features + visibility -> shading
        from prt_torch.commands.bench_play_deformable import run as run_deformable

        return run_deformable(args)
    from prt_torch import limits
    from prt_torch.commands import _validate as V
    from prt_torch.errors import PrtError, check
    from prt_torch.export.graphs import PRECISIONS
    from prt_torch.export.onnx_file import initializer_bytes, weight_macs
    from prt_torch.player import Player
    from prt_torch.progress import make_console
    from prt_torch.rundir import RunDir

    limits.check_int(args.frames, "--frames", 5, limits.MAX_FRAMES)
    limits.check_int(args.repeats, "--repeats", 1, limits.MAX_REPEATS)
    limits.check_int(args.warmup, "--warmup", 1, limits.MAX_REPEATS)
    limits.check_int(args.raytrace_frames, "--raytrace-frames", 0, limits.MAX_REPEATS)
    limits.check_int(args.rays, "--rays", 0, limits.MAX_RAYS)
    limits.check_int(args.batch, "--batch", 1, limits.MAX_BATCH)
    limits.check_int(args.threads, "--threads", 1, limits.MAX_THREADS)
    limits.check_int(args.crowd_chunk, "--crowd-chunk", 0, limits.MAX_BATCH)
    crowds = _parse_sizes(args.crowd, "--crowd", limits.MAX_BATCH)
    if args.batch not in crowds:
        crowds = sorted({*crowds, args.batch})
    precisions = [p.strip() for p in args.precisions.split(",") if p.strip()]
    for p in precisions:
        check(p in PRECISIONS, f"--precisions: unknown precision {p!r} (expected {list(PRECISIONS)})")
    if not args.brdf.strip():
        raise PrtError("--brdf: empty name")
    from prt_torch.player.peaks import PEAK_KINDS, check_peaks_arg

    peaks_arg = check_peaks_arg(args.peaks)
    check(args.peak_visibility is None or args.peak_visibility in PEAK_KINDS,
          f"--peak-visibility: unknown kind {args.peak_visibility!r}: expected one of {', '.join(PEAK_KINDS)}")
    V.input_dir(args.run, "run directory")
    if args.scaling:
        V.output_file(args.plot, "--plot")
    console = make_console(stderr=True)
    run_dir = Path(args.run)
    run = RunDir(run_dir)
    kw = {"brdf": args.brdf, "threads": args.threads, "device": args.device}
    player = Player(run_dir, graph="fused", **kw)
    # the default CPU path (the compiled pass) where the export ships it: the frame figures are its own
    from prt_torch.player.compiled import has_compiled_path

    comp = Player(run_dir, graph="compiled", **kw) if args.device == "cpu" and has_compiled_path(player.bundle) \
        else None
    default = comp if comp is not None else player
    split = Player(run_dir, graph="split", **kw)
    # the frames with peak lights: the same fused path plus the peaks' term (``None``: --peaks 0)
    with_peaks = None if peaks_arg == 0 else Player(run_dir, graph="fused", peaks=peaks_arg,
                                                    peak_kind=args.peak_visibility, **kw)
    if with_peaks is not None and not with_peaks.peaks.peaks:
        with_peaks.close()
        with_peaks = None
    # the same frame through the one graph with the peak term (learned blockers shipped in fused_peaks.onnx)
    fused_peaks = None
    if with_peaks is not None and with_peaks.peak_source is not None and with_peaks.peak_source.kind == "learned" \
            and run.fused_peaks_graph_path.is_file():
        fused_peaks = Player(run_dir, graph="fused_peaks", peaks=peaks_arg, **kw)
    meta = player.bundle.meta
    clips = list(player.character.clips)
    check(bool(clips), f"{run_dir}: the character has no clips")
    clip = max(clips, key=lambda c: player.character.clip(c).num_frames)
    locals_ = player.clip_locals(clip)
    n_clip = len(locals_)
    order, n_v = player.order, player.bundle.n_vertices
    n_terms, n_lobes = int(player.rpo.M.shape[0]), int(player.lighting.dirs.shape[0])
    n_joints = player.character.num_joints

    # -- machine rates (before) ----------------------------------------------------------------------
    fused_path = run.graph_path("fused")
    model_bytes = initializer_bytes(fused_path) + player.rpo.M.nbytes + player.rpo.w.nbytes \
        + player.lighting.coeffs.nbytes
    macs = weight_macs(fused_path)
    ws = max(model_bytes, 1 << 22)
    with console.status("measuring copy bandwidth and GEMM rate ..."):
        bws = [copy_bandwidth(ws, 20)]
        gemms = [gemm_rate(n_v, order * order, n_terms, args.threads)]
        bw_dram = copy_bandwidth(1 << 28, 3)

    # -- precision variants of the visibility model (side by side) ----------------------------------------
    from prt_torch.runtime.session import OrtGraph

    tmp = tempfile.TemporaryDirectory(prefix="prt_bench_play_")
    prec_graphs: dict[str, OrtGraph] = {}
    if precisions:
        with console.status(f"exporting the visibility model at {', '.join(precisions)} ..."):
            prec_graphs = _precision_graphs(run, precisions, Path(tmp.name), args.threads, args.device)

    # -- per-frame path: fused frames, split frames, precision variants, interleaved ------------------------
    times: dict[str, list[float]] = {k: [] for k in ("posing", "fused", "frame", "split_posing", "visibility",
                                                      "shading", *(f"visibility_{p}" for p in prec_graphs),
                                                      "posing_onnx", "frame_posing_onnx", "frame_chained",
                                                      "frame_peaks", "frame_no_peaks", "peak_visibility",
                                                      "peak_shading", "frame_peaks_numba_threads",
                                                      "frame_fused_peaks", "posing_compiled", "compiled",
                                                      "frame_compiled")}
    posing_onnx = _posing_onnx(player, run, Path(tmp.name), args.threads, args.device)  # None without torch
    blocks: list[float] = []
    with console.status(f"timing {args.repeats} x {args.frames} frames on '{clip}' ..."):
        for rep in range(args.repeats):
            block: list[float] = []
            for i in range(args.warmup + args.frames):
                j = (rep * 37 + i) % n_clip
                loc = locals_[j:j + 1]
                pt: dict[str, float] = {}
                if comp is not None:
                    ta = time.perf_counter()
                    cs = comp.pose(loc)
                    tb = time.perf_counter()
                    comp.shade(cs, checked=False)
                    tc = time.perf_counter()
                    pt.update({"posing_compiled": tb - ta, "compiled": tc - tb, "frame_compiled": tc - ta})
                t0 = time.perf_counter()
                state = player.pose(loc)
                t1 = time.perf_counter()
                player.shade(state, checked=False)
                t2 = time.perf_counter()
                s2 = split.pose(loc)
                t3 = time.perf_counter()
                vis = split.visibility(s2.features, checked=False)
                t4 = time.perf_counter()
                split.shade(s2, visibility=vis, checked=False)
                t5 = time.perf_counter()
                if posing_onnx is not None:  # issue 14 item 3: the posing in ONNX, and chained with the fused graph
                    pg, cg, cfeeds = posing_onnx
                    loc32 = loc.astype(np.float32)
                    ta = time.perf_counter()
                    pg.run_unchecked({"local": loc32, "eye": cfeeds["posing/eye"]})
                    tb = time.perf_counter()
                    cfeeds["posing/local"] = loc32
                    cg.run_unchecked(cfeeds)
                    pt.update({"posing_onnx": tb - ta, "frame_posing_onnx": tb - ta + t2 - t1,
                               "frame_chained": time.perf_counter() - tb})
                for p, g in prec_graphs.items():
                    ta = time.perf_counter()
                    g.run_unchecked({"pose": s2.features})
                    pt[p] = time.perf_counter() - ta
                if with_peaks is not None:  # the whole frame with its peaks, next to the same frame without them
                    pt.update(_peak_frame(with_peaks, player, loc, fused_peaks))
                if i < args.warmup:
                    continue
                for k, v in (("posing", t1 - t0), ("fused", t2 - t1), ("frame", t2 - t0), ("split_posing", t3 - t2),
                             ("visibility", t4 - t3), ("shading", t5 - t4)):
                    times[k].append(v)
                for p, v in pt.items():
                    times[p if p in times else f"visibility_{p}"].append(v)
                block.append(pt["frame_compiled"] if comp is not None else t2 - t0)
            blocks.append(_median_ms(block))
    frame_ms = _median_ms(times["frame_compiled"] if comp is not None else times["frame"])
    fps = 1e3 / frame_ms

    # -- crowds: N characters per call of every graph, each crowd call next to a single-character frame ------
    # (blocks per N: one batch size at a time, as a game plays it; the single frames give a same-moment baseline)
    crowd_t: dict[int, list[float]] = {n: [] for n in crowds}
    crowd_single: dict[int, list[float]] = {n: [] for n in crowds}
    crowd_chunked: dict[int, list[float]] = {n: [] for n in crowds}
    chunk = args.crowd_chunk
    crowd_clips = [clips[i % len(clips)] for i in range(max(crowds))]
    with console.status(f"crowds of {crowds} characters ..."):
        for rep in range(args.repeats):
            for n in crowds:
                n_iter = max(3, min(args.frames // 5, 4 * args.frames // n))
                for i in range(2 + n_iter):
                    loc = player.crowd_locals(crowd_clips[:n], rep * 11 + i, stagger=3)
                    t0 = time.perf_counter()
                    state = default.pose(loc)
                    default.shade(state, checked=False)
                    t1 = time.perf_counter()
                    state = default.pose(loc[:1])
                    default.shade(state, checked=False)
                    t2 = time.perf_counter()
                    if chunk and n > chunk and comp is None:  # chunks: the fused graph's (one compiled pass is one)
                        player.crowd_chunk = chunk
                        state = player.pose(loc)
                        player.shade(state, checked=False)
                        player.crowd_chunk = None
                    if i >= 2:
                        crowd_t[n].append(t1 - t0)
                        crowd_single[n].append(t2 - t1)
                        if chunk and n > chunk and comp is None:
                            crowd_chunked[n].append(time.perf_counter() - t2)

    # -- Embree ray tracing of the same frames + shading ------------------------------------------------
    raytrace_ms = speedup = float("nan")
    n_rays = 0
    if args.raytrace_frames:
        raytrace_ms, n_rays = _raytrace(player, split, run, locals_, args, console)
        speedup = raytrace_ms / frame_ms

    # -- machine rates (after); the best of before/after bounds the steps --------------------------------
    bws.append(copy_bandwidth(ws, 20))
    gemms.append(gemm_rate(n_v, order * order, n_terms, args.threads))
    bw, gemm = max(bws), max(gemms)

    costs = step_costs(n_v, order, n_terms, n_lobes, n_joints, model_bytes, macs)
    vis_bytes = initializer_bytes(run.graph_path("visibility"))
    costs["visibility"]["bytes"] += vis_bytes - model_bytes  # the split visibility graph's own weights
    costs["frame"] = {k: costs["posing"][k] + costs["fused"][k] for k in ("bytes", "flops")}
    steps: dict[str, dict[str, Any]] = {}
    for name, key in (("posing", "posing"), ("visibility", "visibility"), ("shading", "shading"),
                      ("fused", "fused"), ("frame", "frame")):
        b = bound(costs[name], bw, gemm)
        ms = _median_ms(times[key])
        steps[name] = {"ms": ms, **b, "fraction": b["bound_ms"] / ms, **costs[name]}
    # the frame's bound: its sequential steps' bounds added (posing, then the fused call)
    steps["frame"]["bound_ms"] = steps["posing"]["bound_ms"] + steps["fused"]["bound_ms"]
    steps["frame"]["fraction"] = steps["frame"]["bound_ms"] / steps["frame"]["ms"]
    roofline_fraction = steps["frame"]["fraction"]
    if comp is not None:  # the default path: compiled posing + the compiled pass; its own bytes and FLOPs
        ccost = _compiled_costs(comp, n_v, order, n_terms, n_lobes)
        for name in ("posing_compiled", "compiled"):
            b = bound(ccost[name], bw, gemm)
            ms = _median_ms(times[name])
            steps[name] = {"ms": ms, **b, "fraction": b["bound_ms"] / ms, **ccost[name]}
        steps["frame_fused"] = steps.pop("frame")
        fc = {k: ccost["posing_compiled"][k] + ccost["compiled"][k] for k in ("bytes", "flops")}
        b_ms = steps["posing_compiled"]["bound_ms"] + steps["compiled"]["bound_ms"]
        ms = _median_ms(times["frame_compiled"])
        steps["frame"] = {"ms": ms, **bound(fc, bw, gemm), **fc, "bound_ms": b_ms, "fraction": b_ms / ms}
        roofline_fraction = steps["frame"]["fraction"]
    if times["posing_onnx"]:  # same bytes / FLOPs as the numpy steps they replace
        ff = "frame_fused" if "frame_fused" in steps else "frame"  # the numpy posing + fused frame they replace
        for name, like in (("posing_onnx", "posing"), ("frame_posing_onnx", ff), ("frame_chained", ff)):
            ms = _median_ms(times[name])
            steps[name] = {**steps[like], "ms": ms, "fraction": steps[like]["bound_ms"] / ms}

    peak_row: dict[str, Any] | None = None
    if with_peaks is not None:
        on, off = _median_ms(times["frame_peaks"]), _median_ms(times["frame_no_peaks"])
        src = with_peaks.peak_source
        peak_row = {"n_peaks": len(with_peaks.peaks.peaks), "kind": None if src is None else src.kind,
                    "frame_ms_on": on, "frame_ms_off": off, "fps_on": 1e3 / on, "fps_off": 1e3 / off,
                    "ratio": off / on, "peak_visibility_ms": _median_ms(times["peak_visibility"]),
                    "peak_shading_ms": _median_ms(times["peak_shading"]),
                    "frame_ms_on_numba_threads": _median_ms(times["frame_peaks_numba_threads"]),
                    "bytes_blockers": 0 if src is None else int(src.bytes()),
                    "frame_ms_fused_peaks": _median_ms(times["frame_fused_peaks"]) if fused_peaks is not None
                    else None}

    precision_rows = {}
    for p, g in prec_graphs.items():
        pb = initializer_bytes(g.path)
        c = {"bytes": pb + n_v * order * order * 4, "flops": 2.0 * weight_macs(g.path)}
        ms = _median_ms(times[f"visibility_{p}"])
        precision_rows[p] = {"ms": ms, "bytes_model": int(pb), **bound(c, bw, gemm)}
        precision_rows[p]["fraction"] = precision_rows[p]["bound_ms"] / ms

    crowd_rows = {}
    for n in crowds:
        if comp is not None:
            c = _compiled_costs(comp, n_v, order, n_terms, n_lobes, crowd=n)
            b_ms = bound(c["posing_compiled"], bw, gemm)["bound_ms"] + bound(c["compiled"], bw, gemm)["bound_ms"]
        else:
            c = step_costs(n_v, order, n_terms, n_lobes, n_joints, model_bytes, macs, crowd=n)
            b_ms = bound(c["posing"], bw, gemm)["bound_ms"] + bound(c["fused"], bw, gemm)["bound_ms"]
        ms = _median_ms(crowd_t[n])
        single = _median_ms(crowd_single[n])
        crowd_rows[str(n)] = {"call_ms": ms, "character_fps": n * 1e3 / ms, "bound_ms": b_ms,
                              "bound_character_fps": n * 1e3 / b_ms, "fraction": b_ms / ms,
                              "single_frame_ms_same_moment": single, "speedup_vs_single": n * single / ms}
        if crowd_chunked[n]:
            cm = _median_ms(crowd_chunked[n])
            crowd_rows[str(n)].update({"chunk": chunk, "chunked_call_ms": cm, "chunked_character_fps": n * 1e3 / cm})

    out: dict[str, Any] = {
        "run": str(run_dir), "clip": clip, "path": default.graph, "n_vertices": n_v, "sh_order": order,
        "model_kind": meta["model_kind"],
        "precision": player.bundle.precision, "vertex_order": meta.get("fused_vertex_order", "original"),
        "brdf": player.rpo.name, "brdf_terms": n_terms, "n_lobes": n_lobes, "threads": args.threads,
        "device": args.device, "frames": args.frames, "repeats": args.repeats,
        "fps": fps, "frame_ms": frame_ms, "frame_ms_per_repeat": blocks,
        "roofline_fraction": roofline_fraction, "steps": steps,
        "bytes_model": int(model_bytes), "model_macs": int(macs),
        "machine": {"copy_bandwidth_gb_s": bw / 1e9, "copy_bandwidth_samples_gb_s": [x / 1e9 for x in bws],
                    "copy_bandwidth_dram_gb_s": bw_dram / 1e9, "copy_working_set_bytes": int(ws),
                    "gemm_gflop_s": gemm / 1e9, "gemm_samples_gflop_s": [x / 1e9 for x in gemms]},
        "precisions": precision_rows, "crowd": crowd_rows,
        "batched_character_fps": crowd_rows[str(args.batch)]["character_fps"], "batch": args.batch,
        "raytrace_ms": raytrace_ms, "raytrace_n_rays": n_rays, "speedup_vs_raytrace": speedup,
        "peaks": peak_row,
    }
    if args.scaling:
        out["scaling"] = _scaling(run, player, args, bw, gemm, console, tmp.name)
        _plot(out, Path(args.plot))
        out["scaling"]["plot"] = str(args.plot)
    player.close()
    split.close()
    for p in (with_peaks, fused_peaks, comp):
        if p is not None:
            p.close()
    tmp.cleanup()
    if args.json:
        print(json.dumps(out, indent=2, sort_keys=True))
        return 0
    _print_tables(out)
    return 0


def _compiled_costs(comp: Any, n_v: int, order: int, n_terms: int, n_lobes: int,
                    crowd: int = 1) -> dict[str, dict[str, float]]:
    """The compiled path's bytes and FLOPs (:func:`prt_torch.commands.roofline.compiled_costs`) from the player's
    own arrays: the poser's sparse weights, the decode's bases and the latent graph's weights."""
    from prt_torch.export.onnx_file import initializer_bytes, weight_macs

    cf, poser = comp.compiled, comp.poser
    latent = cf.latent.path
    return compiled_costs(n_v, order, n_terms, n_lobes, poser.bytes(), int(poser.weight.size),
                          cf.bytes() + initializer_bytes(latent), weight_macs(latent) + cf.decode_macs(),
                          int(cf.g_v.size), int(cf.sh_v.size), crowd=crowd)


def _peak_frame(with_peaks: Any, without: Any, loc: np.ndarray, fused_peaks: Any = None) -> dict[str, float]:
    """Seconds of one whole frame of ``loc (1, J, 4, 4)`` with the peaks' term (``with_peaks.compute``: posing, the
    fused call, the peaks' visibility and shading) and of the same frame without it (``without``: posing and the
    fused call), then of the peaks' two parts alone on the posed frame, then of the frame with the peak kernels on
    numba's threads (``Player.peak_threads``; the player's default is the calling thread), then (``fused_peaks``: a
    player of graph ``fused_peaks``) of the frame through that one graph."""
    t0 = time.perf_counter()
    state, _ = with_peaks.compute(loc)
    t1 = time.perf_counter()
    without.shade(without.pose(loc), checked=False)
    t2 = time.perf_counter()
    vis = with_peaks.peak_visibility(state)
    t3 = time.perf_counter()
    with_peaks.shade_peaks(state, vis)
    t4 = time.perf_counter()
    default, with_peaks.peak_threads = with_peaks.peak_threads, True  # the peak kernels on numba's threads
    try:
        with_peaks.compute(loc)
    finally:
        with_peaks.peak_threads = default
    t5 = time.perf_counter()
    out = {"frame_peaks": t1 - t0, "frame_no_peaks": t2 - t1, "peak_visibility": t3 - t2, "peak_shading": t4 - t3,
           "frame_peaks_numba_threads": t5 - t4}
    if fused_peaks is not None:
        fused_peaks.compute(loc)
        out["frame_fused_peaks"] = time.perf_counter() - t5
    return out


def _precision_graphs(run: Any, precisions: list[str], tmp: Path, threads: int, device: str) -> dict[str, Any]:
    """The run's visibility model exported at each precision into ``tmp`` (torch): ``{precision: OrtGraph}``."""
    import torch

    from prt_torch.export.graphs import VisibilityGraph
    from prt_torch.export.onnx_file import export_onnx
    from prt_torch.export.run import lowering, per_cluster
    from prt_torch.models.visibility import load_model
    from prt_torch.runtime.session import OrtGraph

    kind = run.export_meta().get("model_kind")
    model = load_model(run, kind)
    if not per_cluster(model):
        return {}
    out = {}
    for p in precisions:
        g = VisibilityGraph(model, cluster_sorted=True, precision=p).eval()
        path = tmp / f"visibility_{p}.onnx"
        export_onnx(g, [torch.zeros(1, model.n_features)], path, ("pose",), ("visibility",),
                    {"pose": {0: "B"}, "visibility": {0: "B"}}, **lowering(p))
        out[p] = OrtGraph(path, threads=threads, device=device)
    return out


def _posing_onnx(player: Any, run: Any, tmp: Path, threads: int, device: str) -> tuple[Any, Any, dict] | None:
    """The posing graph and the posing + fused chained graph of the player's run (exported into ``tmp``) with the
    chained graph's constant feeds, or ``None`` without torch."""
    try:
        import torch  # noqa: F401
    except ImportError:
        return None
    from prt_torch.export.posing_graph import PosingGraph, chain_posing_fused, export_posing_graph
    from prt_torch.runtime.session import OrtGraph

    b = player.bundle
    g = PosingGraph(player.character, b.cluster, b.cluster_axis, b.cluster_bone, order=player.vertex_order)
    path = export_posing_graph(g, tmp / "posing.onnx")
    chained = chain_posing_fused(path, run.graph_path("fused"), tmp / "posing_fused.onnx")
    state = player.pose(player.clip_locals(next(iter(player.character.clips)))[:1])
    feeds = {k: v for k, v in player._fused_feeds(state).items() if k not in ("pose", "frames", "view_dirs")}
    feeds["posing/eye"] = np.asarray(player.eye, np.float32)
    return (OrtGraph(path, threads=threads, device=device), OrtGraph(chained, threads=threads, device=device), feeds)


def _raytrace(player: Any, split: Any, run: Any, locals_: np.ndarray, args: argparse.Namespace,
              console: Any) -> tuple[float, int]:
    """Median ms of Embree ray tracing + shading a frame (the bake's per-frame path) and the rays per vertex."""
    from prt_torch.bake.embree import ray_offset
    from prt_torch.bake.trace import RaySet, trace_frame

    ds_attrs = run.dataset().attrs if run.dataset_path.exists() else {}
    n_rays = int(args.rays or ds_attrs.get("n_rays") or 128)
    rel_offset = float((ds_attrs.get("bake") or {}).get("ray_offset", 1e-4))
    rays = RaySet.make(n_rays, player.order, player.bundle.n_vertices, seed=0)
    offset = ray_offset(player.character.rest_vertices, rel_offset)
    faces = player.character.faces
    rt: list[float] = []
    with console.status(f"ray-tracing {args.raytrace_frames} frames with Embree ({n_rays} rays/vertex) ..."):
        for j in range(args.raytrace_frames):
            loc = locals_[(j * 7) % len(locals_):(j * 7) % len(locals_) + 1]
            t0 = time.perf_counter()
            state = split.pose(loc)
            res = trace_frame(state.positions_vx3(0), state.frames_vx33()[0], faces, rays, offset)
            split.shade(state, visibility=res.visibility[None], checked=False)
            rt.append(time.perf_counter() - t0)
    return _median_ms(rt), n_rays


def synthetic_model(template: Any, character: Any, seed: int = 0) -> Any:
    """A :class:`~prt_torch.models.visibility.VisibilityModel` for ``character`` with ``template``'s structure
    (input projection, regressor, the number of clusters and components per cluster) and random per-cluster
    bases: vertices split into equal clusters along the skin's dominant joint - a timing stand-in only."""
    import torch

    from prt_torch.models.projection import OutputUnprojection
    from prt_torch.models.visibility import VisibilityModel

    out = template.out
    g_count, k_max = int(out.basis.shape[0]), int(out.basis.shape[1])
    k_used = [int((out.basis[g].abs().sum(1) > 0).sum()) for g in range(g_count)]
    v, c = character.num_vertices, int(out.n_coeffs)
    dom = np.argmax(character.dense_weights, axis=1)
    order = np.lexsort((np.arange(v), dom))
    labels = np.empty(v, np.int64)
    labels[order] = np.minimum(np.arange(v) * g_count // v, g_count - 1)
    counts = np.bincount(labels, minlength=g_count)
    l_max = int(counts.max()) * c
    rng = np.random.default_rng(seed)
    basis = np.zeros((g_count, k_max, l_max), np.float32)
    gather = np.empty((v, c), np.int64)
    for g in range(g_count):
        verts = np.flatnonzero(labels == g)
        basis[g, :k_used[g], :verts.size * c] = rng.standard_normal((k_used[g], verts.size * c)) * 0.05
        gather[verts] = g * l_max + np.arange(verts.size * c).reshape(verts.size, c)
    mean = rng.standard_normal(v * c).astype(np.float32) * 0.1
    unproj = OutputUnprojection(torch.from_numpy(basis), torch.from_numpy(gather.reshape(-1).astype(np.int32)),
                                torch.from_numpy(mean), v, c)
    return VisibilityModel(template.kind, template.inp, template.regressor, unproj), labels


def _scaling(run: Any, player: Any, args: argparse.Namespace, bw: float, gemm: float, console: Any,
             tmp: str) -> dict[str, Any]:
    """Frame time (pose + fused call) and its bound for the built-in character at :data:`SCALING_DENSITIES`."""
    import torch

    from prt_torch.export.graphs import FUSED_INPUTS, FusedGraph
    from prt_torch.export.onnx_file import export_onnx, initializer_bytes, weight_macs
    from prt_torch.export.run import lowering
    from prt_torch.models.visibility import load_model
    from prt_torch.player.posing import Poser
    from prt_torch.rig.builtin import make_character
    from prt_torch.rig.vertex_frames import cluster_axes, cluster_bones
    from prt_torch.runtime.session import OrtGraph

    template = load_model(run, run.export_meta().get("model_kind"))
    prec = player.bundle.precision
    order, n_terms = player.order, int(player.rpo.M.shape[0])
    cases = []
    for d in SCALING_DENSITIES:
        with console.status(f"scaling: built-in character at density {d} ..."):
            ch = make_character(density=d)
            model, labels = synthetic_model(template, ch)
            fused = FusedGraph(model, order, n_terms, cluster_sorted=True, precision=prec).eval()
            path = Path(tmp) / f"fused_{d}.onnx"
            v = ch.num_vertices
            ex = {"pose": torch.zeros(1, model.n_features), "frames": torch.zeros(1, 9, v),
                  "view_dirs": torch.zeros(1, 3, v), "lobe_dirs": torch.from_numpy(player._lobe_dirs),
                  "lobe_coeffs": torch.from_numpy(player.lighting.coeffs), "rpo_M": torch.from_numpy(player.rpo.M),
                  "rpo_w": torch.from_numpy(player.rpo.w), "rpo_tint": torch.from_numpy(player.rpo.tint)}
            b = {0: "B"}
            export_onnx(fused, [ex[k] for k in FUSED_INPUTS], path, FUSED_INPUTS, ("radiance",),
                        {"pose": b, "frames": b, "view_dirs": b, "radiance": b},
                        **lowering(prec))
            poser = Poser(ch, labels, cluster_axes(ch.rest_vertices, labels), cluster_bones(ch.dense_weights, labels),
                          order=fused.vertex_order)
            cases.append({"density": d, "ch": ch, "graph": OrtGraph(path, threads=args.threads, device=args.device),
                          "poser": poser, "locs": np.asarray(ch.clip("walk").local), "path": path,
                          "feeds": {k: ex[k].numpy() for k in FUSED_INPUTS[3:]}, "frame": [], "posing": []})
    n_iter = max(10, args.frames // 3)
    with console.status(f"scaling: timing {len(cases)} vertex counts interleaved ..."):
        for _rep in range(args.repeats):
            for i in range(3 + n_iter):
                for c in cases:
                    locs, poser = c["locs"], c["poser"]
                    t0 = time.perf_counter()
                    st = poser(locs[i % len(locs):i % len(locs) + 1], player.eye)
                    t1 = time.perf_counter()
                    c["graph"].run_unchecked({"pose": st.features, "frames": st.in_order("frames", poser.order),
                                              "view_dirs": st.in_order("view_dirs", poser.order), **c["feeds"]})
                    if i >= 3:
                        c["frame"].append(time.perf_counter() - t0)
                        c["posing"].append(t1 - t0)
    rows = []
    for c in cases:
        ch, path = c["ch"], c["path"]
        v = ch.num_vertices
        mb = initializer_bytes(path) + player.rpo.M.nbytes + player.rpo.w.nbytes
        cost = step_costs(v, order, n_terms, len(player._lobe_dirs), ch.num_joints, mb, weight_macs(path))
        b_ms = bound(cost["posing"], bw, gemm)["bound_ms"] + bound(cost["fused"], bw, gemm)["bound_ms"]
        ms = _median_ms(c["frame"])
        rows.append({"density": c["density"], "n_vertices": v, "frame_ms": ms, "posing_ms": _median_ms(c["posing"]),
                     "bound_ms": b_ms, "fraction": b_ms / ms, "bytes_model": int(mb)})
    return {"precision": prec, "vertices": rows}


def _plot(out: dict[str, Any], path: Path) -> None:
    """Two panels: frame time and bound vs vertex count; per-character time and bound vs crowd size."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from prt_torch.io import atomic_path

    rows = out["scaling"]["vertices"]
    fig, ax = plt.subplots(1, 2, figsize=(10, 4))
    v = [r["n_vertices"] for r in rows]
    ax[0].loglog(v, [r["frame_ms"] for r in rows], "o-", label="measured frame (pose + fused)")
    ax[0].loglog(v, [r["posing_ms"] for r in rows], "s--", label="measured posing")
    ax[0].loglog(v, [r["bound_ms"] for r in rows], "k:", label="roofline bound")
    ax[0].set_xticks(v, [f"{x / 1000:.1f}k" for x in v], minor=False)
    ax[0].set_xticks([], minor=True)
    ax[0].set_xlabel("vertices")
    ax[0].set_ylabel("ms per frame")
    ax[0].set_title(f"one character ({out['scaling']['precision']} bases)")
    ax[0].grid(True, which="both", alpha=0.3)
    ax[0].legend()
    crowd = out["crowd"]
    n = [int(k) for k in crowd]
    ax[1].loglog(n, [crowd[k]["call_ms"] / int(k) for k in crowd], "o-", label="measured, per character")
    ax[1].loglog(n, [crowd[k]["bound_ms"] / int(k) for k in crowd], "k:", label="roofline bound, per character")
    ax[1].set_xticks(n, [str(x) for x in n], minor=False)
    ax[1].set_xticks([], minor=True)
    ax[1].set_xlabel("characters per call (crowd)")
    ax[1].set_ylabel("ms per character-frame")
    ax[1].set_title(f"crowd, {out['n_vertices']} vertices each")
    ax[1].grid(True, which="both", alpha=0.3)
    ax[1].legend()
    fig.suptitle(f"prt bench play: {out['threads']} ORT threads, {out['device']}, "
                 f"{out['machine']['copy_bandwidth_gb_s']:.0f} GB/s, {out['machine']['gemm_gflop_s']:.0f} GFLOP/s")
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=110, format="png")
    plt.close(fig)


def _print_tables(out: dict[str, Any]) -> None:
    from rich.table import Table

    from prt_torch.progress import make_console

    m = out["machine"]
    t = Table(title=f"prt bench play: {out['run']} ({out['n_vertices']} vertices, order {out['sh_order']}, "
                    f"{out['model_kind']} {out['precision']}, {out['brdf']} k={out['brdf_terms']}, {out['threads']} "
                    f"ORT threads, {out['device']}); copy {m['copy_bandwidth_gb_s']:.0f} GB/s, GEMM "
                    f"{m['gemm_gflop_s']:.0f} GFLOP/s (this run)")
    for col in ("step", "measured ms", "bound ms", "fraction", "bound by", "MB", "MFLOP"):
        t.add_column(col, justify="right" if col != "step" else "left")
    for name, s in out["steps"].items():
        t.add_row(name, f"{s['ms']:.3f}", f"{s['bound_ms']:.3f}", f"{s['fraction']:.2f}", s["bound_by"],
                  f"{s['bytes'] / 1e6:.2f}", f"{s['flops'] / 1e6:.1f}")
    path = "posing_compiled + compiled" if out.get("path") == "compiled" else "posing + fused"
    t.add_row(f"fps (frame = {path})", f"{out['fps']:.0f}", "", f"{out['roofline_fraction']:.2f}", "", "", "")
    for p, r in out["precisions"].items():
        t.add_row(f"visibility graph {p}", f"{r['ms']:.3f}", f"{r['bound_ms']:.3f}", f"{r['fraction']:.2f}",
                  r["bound_by"], f"{r['bytes_model'] / 1e6:.2f}", "")
    for n, r in out["crowd"].items():
        t.add_row(f"crowd {n}: per call ({r['character_fps']:.0f} character-frames/s, {r['speedup_vs_single']:.2f}x "
                  f"single frames timed alongside)", f"{r['call_ms']:.2f}",
                  f"{r['bound_ms']:.2f}", f"{r['fraction']:.2f}", "", "", "")
        if "chunked_call_ms" in r:
            t.add_row(f"crowd {n} in calls of {r['chunk']} ({r['chunked_character_fps']:.0f} character-frames/s)",
                      f"{r['chunked_call_ms']:.2f}", f"{r['bound_ms']:.2f}",
                      f"{r['bound_ms'] / r['chunked_call_ms']:.2f}", "", "", "")
    pk = out.get("peaks")
    if pk:
        t.add_row(f"frame with {pk['n_peaks']} peak(s) ({pk['kind'] or 'no blockers'}): {pk['fps_on']:.0f} frames/s "
                  f"vs {pk['fps_off']:.0f} without, ratio {pk['ratio']:.2f}", f"{pk['frame_ms_on']:.3f}", "", "", "",
                  "", "")
        t.add_row(f"  peak kernels on numba's threads: {1e3 / pk['frame_ms_on_numba_threads']:.0f} frames/s",
                  f"{pk['frame_ms_on_numba_threads']:.3f}", "", "", "", "", "")
        t.add_row(f"  peak visibility / peak shading (frame without peaks {pk['frame_ms_off']:.3f} ms)",
                  f"{pk['peak_visibility_ms']:.3f} / {pk['peak_shading_ms']:.3f}", "", "", "", "", "")
        if pk.get("frame_ms_fused_peaks"):
            t.add_row(f"  one graph, fused_peaks.onnx: {1e3 / pk['frame_ms_fused_peaks']:.0f} frames/s",
                      f"{pk['frame_ms_fused_peaks']:.3f}", "", "", "", "", "")
    t.add_row(f"Embree ray trace ({out['raytrace_n_rays']} rays/vertex) + shading; speed-up",
              f"{out['raytrace_ms']:.0f}", "", f"{out['speedup_vs_raytrace']:.0f}x", "", "", "")
    if "scaling" in out:
        for r in out["scaling"]["vertices"]:
            t.add_row(f"scaling: {r['n_vertices']} vertices (pose + fused)", f"{r['frame_ms']:.3f}",
                      f"{r['bound_ms']:.3f}", f"{r['fraction']:.2f}", "", f"{r['bytes_model'] / 1e6:.2f}", "")
    make_console().print(t)

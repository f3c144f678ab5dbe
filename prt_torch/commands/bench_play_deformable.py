"""``prt bench play RUN`` on a DEFORMABLE (cloth) run: frames/s of the run-time path, measured side by side.

``prt bench play`` hands a run whose export has a ``deformable`` entry to :func:`run` here (same arguments). On the
run's held-out frames (the dataset's ``positions``; the cached sequences hold the same), everything timed interleaved
frame by frame in ``--repeats`` blocks, medians reported (:class:`prt_torch.cloth.player.DeformablePlayer`):

* ``frames``: numpy :meth:`FrameOperator.frames_soa` + view directions (the player's "pose" step);
* ``features_numpy``: the player's numpy dihedral angles (:class:`prt_torch.deform.dihedral_soa.DihedralSoA`);
  ``visibility_numpy``: those features + the pose graph (the player's default visibility step);
* ``positions_<precision>``: the positions-in graph (dihedral angles -> model -> visibility) at every weight precision
  (the shipped one, and ``--precisions`` exported into a temporary directory); ``visibility_pose``: the shipped pose
  graph on the dataset's features (so ``features ~= positions - visibility_pose`` is the dihedral angles' cost);
* ``shading``: the shading graph (RPO, ``--brdf``);
* ``frame_<mode>``: the player's whole per-frame path (``compute``): split / overlap / fused with the numpy
  features (the default; fused: into ``fused.onnx``), ``*_graphfeat`` with the positions graph's features (the
  previous path), ``*_1thread`` with one onnxruntime thread (the better setting on a loaded 2-core machine) -
  ``fps``. Spinning threads are not compared here: a spinning pool keeps its cores busy after its call and slows
  whatever is timed next (measure them in separate processes: the player's ``spinning=``);
* ``stream_<mode>``: sequence playback (``compute_stream`` over the held-out frames, wall time / frames): split and
  overlap one frame at a time, pipeline with the next frame's stage in flight (one frame of latency);
* a run shipping a LOCAL network (``export.json`` ``local``): every row above plays the per-cluster model
  (``local=False``), and ``local_offsets`` (numba; ``local_offsets_numpy`` the numpy rule beside it),
  ``local_visibility`` (offsets + ``local.onnx``), ``frame_split_local``, ``stream_split_local`` and
  ``stream_pipeline_local`` (two whole frames in flight) play the local one;
* ``ratios``: new / old of each compared pair, side by side (``< 1``: the new variant is faster);
* the roofline of :mod:`prt_torch.commands.bench_play` (copy bandwidth, GEMM rate, bytes and FLOPs per step) for the
  frame's lower bound and ``roofline_fraction``.
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

HELP = "Frames/s of a deformable run's run-time path (positions -> frames + features + visibility -> shading)."


def _positions_graphs(run: Any, precisions: list[str], tmp: Path, threads: int, device: str) -> dict[str, Any]:
    """The run's positions-in graph exported at each precision into ``tmp`` (torch): ``{precision: OrtGraph}``."""
    import torch

    from prt_torch.cloth.deform_data import DeformData
    from prt_torch.cloth.export import graph_input_names, positions_graph_module
    from prt_torch.export.graphs import VisibilityGraph
    from prt_torch.export.onnx_file import export_onnx
    from prt_torch.export.run import lowering, per_cluster
    from prt_torch.models.visibility import load_model
    from prt_torch.runtime.session import OrtGraph

    model = load_model(run, run.export_meta().get("model_kind"))
    if not per_cluster(model):
        return {}
    d = DeformData.load(run.deform_path)
    names = graph_input_names(d.n_body_features)
    rest = torch.as_tensor(np.asarray(run.character().rest_vertices, np.float32))[None]
    out = {}
    for p in precisions:
        module = positions_graph_module(VisibilityGraph(model, precision=p).eval(), d.edges, d.n_body_features)
        path = tmp / f"positions_{p}.onnx"
        export_onnx(module, [rest, torch.zeros(1, d.n_body_features)][:len(names)], path, names, ("visibility",),
                    {k: {0: "B"} for k in (*names, "visibility")}, **lowering(p))
        out[p] = OrtGraph(path, threads=threads, device=device)
    return out


def run(args: argparse.Namespace) -> int:
    from prt_torch import limits
    from prt_torch.cloth.player import DeformablePlayer
    from prt_torch.commands.roofline import bound, copy_bandwidth, gemm_rate, step_costs
    from prt_torch.errors import check
    from prt_torch.export.graphs import PRECISIONS
    from prt_torch.export.onnx_file import initializer_bytes, weight_macs
    from prt_torch.progress import make_console
    from prt_torch.rundir import RunDir

    limits.check_int(args.frames, "--frames", 5, limits.MAX_FRAMES)
    limits.check_int(args.repeats, "--repeats", 1, limits.MAX_REPEATS)
    limits.check_int(args.warmup, "--warmup", 1, limits.MAX_REPEATS)
    limits.check_int(args.threads, "--threads", 1, limits.MAX_THREADS)
    precisions = [p.strip() for p in args.precisions.split(",") if p.strip()]
    for p in precisions:
        check(p in PRECISIONS, f"--precisions: unknown precision {p!r} (expected {list(PRECISIONS)})")
    console = make_console(stderr=True)
    run_dir = RunDir(args.run)
    local_meta = run_dir.export_meta().get("local")
    local_kind = local_meta.get("kind") if isinstance(local_meta, dict) else None  # the shipped local network's
    has_local = local_kind is not None

    def make(graph: str, threads: int = args.threads, **kw: Any) -> DeformablePlayer:
        kw.setdefault("local", False if has_local else None)  # the per-cluster rows play the per-cluster model
        return DeformablePlayer(run_dir, brdf=args.brdf, threads=threads, device=args.device, graph=graph, **kw)

    player = make("split")
    variants = {"frame_split": player, "frame_split_graphfeat": make("split", features="graph"),
                "frame_split_1thread": make("split", threads=1), "frame_overlap": make("overlap"),
                "frame_overlap_graphfeat": make("overlap", features="graph"), "frame_fused": make("fused"),
                "frame_fused_graphfeat": make("fused", features="graph")}
    local_player = make("split", local=True) if has_local else None
    if local_player is not None:  # the shipped local network: frames, offsets (numba), local.onnx
        variants["frame_split_local"] = local_player
        from prt_torch.local.soa import LocalOffsetsSoA

        numpy_offsets = LocalOffsetsSoA(local_player.local_offsets.neighbours, engine="numpy")
    try:
        ds = run_dir.dataset()
        rows = ds.split_rows("heldout") if "heldout" in ds.splits else np.flatnonzero(ds.done)
        rows = rows[: max(args.frames, 1)]
        data = ds.rows(rows, ("pose", "positions"))
        pos = np.asarray(data["positions"], np.float32)
        pose = np.asarray(data["pose"], np.float32)
        nb = player.n_body
        body = pose[:, pose.shape[1] - nb:] if nb else None
        seq = player.make_sequence(pos, body, name="heldout")
        for q in variants.values():
            q.exposure = player.exposure
        n = len(seq)
        with tempfile.TemporaryDirectory() as tmp:
            graphs = _positions_graphs(run_dir, [p for p in precisions if p != player.bundle.precision], Path(tmp),
                                       args.threads, args.device)
            graphs[f"{player.bundle.precision} (shipped)"] = player.positions_graph
            times: dict[str, list[float]] = {k: [] for k in ("frames", "features_numpy", "visibility_numpy",
                                                             "visibility_pose", "shading", *variants,
                                                             *(f"positions_{p}" for p in graphs),
                                                             *(("local_offsets", "local_offsets_numpy",
                                                                "local_visibility")
                                                               if local_player is not None else ()))}
            vis_pose = player.bundle.graphs["visibility"]
            shade_vis = player.visibility_from_positions(pos[:1], None if body is None else body[:1])

            def one(i: int, record: bool) -> None:
                sl = slice(i, i + 1)
                p_i, s_i, b_i = seq[sl]
                feeds = player._vis_feeds(p_i, b_i)
                steps = [("frames", lambda: player.frames(s_i)),
                         ("visibility_pose", lambda: vis_pose.run_unchecked({"pose": pose[sl]})),
                         ("features_numpy", lambda: player.pose_features(s_i, b_i)),
                         ("visibility_numpy", lambda: player._visibility_numpy(s_i, b_i)),
                         ("shading", lambda: player.shade(state, visibility=shade_vis, checked=False)),
                         *((k, (lambda q=q: q.compute((p_i, s_i, b_i)))) for k, q in variants.items()),
                         *((f"positions_{p}", (lambda g=g: g.run_unchecked(feeds))) for p, g in graphs.items())]
                if local_player is not None:
                    steps += [("local_offsets", lambda: local_player.local_offsets(s_i, state.frames)),
                              ("local_offsets_numpy", lambda: numpy_offsets(s_i, state.frames)),
                              ("local_visibility", lambda: local_player._local_visibility(s_i, state))]
                state = player.frames(s_i)
                k = i % len(steps)  # rotate the order each frame
                for name, fn in steps[k:] + steps[:k]:
                    t0 = time.perf_counter()
                    fn()
                    if record:
                        times[name].append(time.perf_counter() - t0)

            for i in range(args.warmup):
                one(i % n, False)
            for _ in range(args.repeats):
                for i in range(n):
                    one(i, True)
            # sequence playback (Player.compute_stream over the whole sequence, ms per frame = wall / frames): split
            # and overlap one frame at a time, pipeline with the next frame's stage in flight; interleaved repeats
            streams = {"stream_split": player, "stream_overlap": variants["frame_overlap"],
                       "stream_pipeline": make("pipeline")}
            variants["stream_pipeline"] = streams["stream_pipeline"]
            streams["stream_pipeline"].exposure = player.exposure
            if local_player is not None:
                streams["stream_split_local"] = local_player
                streams["stream_pipeline_local"] = variants["stream_pipeline_local"] = make("pipeline", local=True)
                streams["stream_pipeline_local"].exposure = player.exposure
            for q in streams.values():
                for _ in q.compute_stream(seq, min(n, args.warmup)):
                    pass
            for _ in range(args.repeats):
                for name, q in streams.items():
                    t0 = time.perf_counter()
                    for _ in q.compute_stream(seq, n):
                        pass
                    times.setdefault(name, []).append((time.perf_counter() - t0) / n)
        ms = {k: float(np.median(v) * 1e3) for k, v in times.items() if v}
        bw, gemm = copy_bandwidth(), gemm_rate(player.bundle.n_vertices, player.order ** 2, player.bundle.n_terms,
                                               args.threads)
        shipped = player.positions_graph.path
        mbytes, macs = initializer_bytes(shipped), weight_macs(shipped)
        costs = step_costs(player.bundle.n_vertices, player.order, player.bundle.n_terms, len(player.lighting.dirs),
                           1, mbytes, macs)
        bounds = {k: bound(c, bw, gemm) for k, c in costs.items()}
        frame_bound = bounds["visibility"]["bound_ms"] + bounds["shading"]["bound_ms"] + \
            bounds["posing"]["bound_ms"]
        prec = player.bundle.precision
        frame_keys = ("frame_split", "frame_overlap", "frame_fused")
        best = min(ms[k] for k in frame_keys)
        old_best = min(ms[k] for k in ("frame_split_graphfeat", "frame_overlap_graphfeat", "frame_fused_graphfeat"))
        pairs = {"visibility: numpy features + pose graph / positions graph":
                 ("visibility_numpy", f"positions_{prec} (shipped)"),
                 "features: numpy / positions graph's": ("features_numpy", None),
                 "frame split: numpy features / graph features": ("frame_split", "frame_split_graphfeat"),
                 "frame overlap: numpy features / graph features": ("frame_overlap", "frame_overlap_graphfeat"),
                 "frame fused: numpy features / graph features": ("frame_fused", "frame_fused_graphfeat"),
                 f"frame split: 1 / {args.threads} onnxruntime thread(s)": ("frame_split_1thread", "frame_split"),
                 "frame overlap / split": ("frame_overlap", "frame_split"),
                 "frame fused / split": ("frame_fused", "frame_split"),
                 "sequence playback: pipeline / split": ("stream_pipeline", "stream_split"),
                 "sequence playback: pipeline / overlap": ("stream_pipeline", "stream_overlap")}
        if local_player is not None:
            pairs.update({"local offsets: numba / numpy": ("local_offsets", "local_offsets_numpy"),
                          "visibility: local (offsets + network) / per-cluster (numpy features + pose graph)":
                          ("local_visibility", "visibility_numpy"),
                          "frame split: local / per-cluster": ("frame_split_local", "frame_split"),
                          "sequence playback: local pipeline / per-cluster pipeline":
                          ("stream_pipeline_local", "stream_pipeline"),
                          "sequence playback: local pipeline / local split": ("stream_pipeline_local",
                                                                             "stream_split_local")})
        feat_graph = ms[f"positions_{prec} (shipped)"] - ms["visibility_pose"]
        ratios = {k: ms[a] / (ms[b] if b else feat_graph) for k, (a, b) in pairs.items()}
        ratios["best frame: new / old (graph features)"] = best / old_best
        out: dict[str, Any] = {
            "run": str(run_dir.path), "n_vertices": player.bundle.n_vertices, "sh_order": player.order,
            "n_edges": int(player.deform.edges.shape[0]), "n_body_features": nb, "precision": prec,
            "frames_timed": n * args.repeats, "threads": args.threads, "device": args.device,
            "fps": 1e3 / best, "fps_fused": 1e3 / ms["frame_fused"], "fps_split": 1e3 / ms["frame_split"],
            "fps_overlap": 1e3 / ms["frame_overlap"], "fps_old": 1e3 / old_best,
            "fps_pipeline": 1e3 / ms["stream_pipeline"], "fps_stream_split": 1e3 / ms["stream_split"],
            **({"fps_pipeline_local": 1e3 / ms["stream_pipeline_local"],
                "fps_stream_split_local": 1e3 / ms["stream_split_local"],
                "local": local_kind} if local_player is not None else {}),
            "fps_variants": {k: 1e3 / ms[k] for k in variants if k in ms}, "ratios": ratios,
            "steps_ms": ms, "features_ms": feat_graph,
            "bytes_model": mbytes, "roofline": {"frame_bound_ms": frame_bound, "roofline_fraction": frame_bound / best,
                                                "steps": bounds},
            "machine": {"copy_bandwidth_gb_s": bw / 1e9, "gemm_gflop_s": gemm / 1e9},
        }
    finally:
        for q in variants.values():
            q.close()
    if args.json:
        print(json.dumps(out, indent=1))
        return 0
    console.print(f"deformable run {out['run']}: {out['n_vertices']} vertices, {out['n_edges']} dihedral angles"
                  f"{f' + {nb} body features' if nb else ''}, order {out['sh_order']}, {prec} bases, "
                  f"{args.threads} thread(s), {args.device}")
    for k, v in sorted(ms.items(), key=lambda kv: -kv[1]):
        console.print(f"  {k:<28} {v:8.3f} ms")
    console.print(f"  features (positions - pose graph) ~ {out['features_ms']:.3f} ms")
    console.print(f"frame: {out['fps']:.0f} frames/s (fused {out['fps_fused']:.0f}, split {out['fps_split']:.0f}, "
                  f"overlap {out['fps_overlap']:.0f});"
                  f" roofline bound {frame_bound:.3f} ms -> fraction {out['roofline']['roofline_fraction']:.2f}")
    console.print("side by side (new / old; < 1: faster):")
    for k, r in ratios.items():
        console.print(f"  {k:<56} {r:6.3f}  (x{1 / r:.2f})")
    console.print(f"frame: {out['fps']:.0f} frames/s now, {out['fps_old']:.0f} frames/s with the graph features")
    console.print(f"sequence playback: {out['fps_pipeline']:.0f} frames/s pipelined (one frame of latency), "
                  f"{out['fps_stream_split']:.0f} frames/s split")
    if "fps_pipeline_local" in out:
        console.print(f"local {out['local']} (shipped): {out['fps_pipeline_local']:.0f} frames/s pipelined, "
                      f"{out['fps_stream_split_local']:.0f} frames/s split")
    return 0

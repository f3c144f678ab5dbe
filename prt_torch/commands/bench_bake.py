"""``prt bench bake``: end-to-end bake throughput vs raw Embree occlusion, measured side by side.

Three measurements in one run, on the built-in character posed by random poses:

* ``raw``: Embree ``OCCLUDED`` queries alone, one process, on every frame's exact rays
  (scene, origins and directions prepared beforehand, not timed), in the bake's ray blocks;
* ``bake``: the full per-block bake task in ONE process (skinning, vertex frames, ray generation,
  tracing, SH projection, zarr chunk writes; store creation and clustering excluded), timed
  block by block alternately with ``raw`` on the same frames (``--rounds`` passes), so that a
  shared machine's drifting load hits both alike; ``ratio`` = median over blocks of
  ``bake rays/s / raw rays/s`` (and ``ratio_of_totals``), BLAS single-threaded in both;
* ``pool``: the same bake with ``--workers`` processes (default: one per core), worker start-up
  included -> ``frames_per_s`` and its rays/s.
"""

from __future__ import annotations

import argparse
import json
import os
import tempfile
import time
from pathlib import Path

HELP = "Bake throughput (rays/s, frames/s) vs raw embreex occlusion on the same posed mesh and rays."


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--density", type=float, default=0.5, help="built-in character density (0.5: ~5.9k verts)")
    parser.add_argument("--rays", type=int, default=512, help="rays per vertex")
    parser.add_argument("--order", type=int, default=4, help="SH order")
    parser.add_argument("--frames", type=int, default=16, help="frames baked per measurement")
    parser.add_argument("--workers", type=int, default=0, help="processes of the pool measurement (0: one per core)")
    parser.add_argument("--rounds", type=int, default=3, help="passes over the frames (raw and bake alternated)")
    parser.add_argument("--json", action="store_true", help="print one JSON object")


def run(args: argparse.Namespace) -> int:
    import numpy as np
    from threadpoolctl import threadpool_limits

    from prt_torch import limits
    from prt_torch.bake.directions import rotated_frames, world_directions
    from prt_torch.bake.embree import RayScene
    from prt_torch.bake.plan import make_plan
    from prt_torch.bake.runner import bake_block, block_tasks, prepare, run_bake
    from prt_torch.bake.store import open_dataset
    from prt_torch.bake.trace import RaySet
    from prt_torch.config import config_from_dict
    from prt_torch.progress import make_console
    from prt_torch.rig.vertex_frames import vertex_frames

    limits.check_float(args.density, "--density", limits.MIN_DENSITY, limits.MAX_DENSITY)
    limits.check_int(args.rays, "--rays", 16, limits.MAX_RAYS)
    limits.check_int(args.order, "--order", 1, 6)
    limits.check_int(args.frames, "--frames", 1, limits.MAX_RANDOM_POSES)
    limits.check_int(args.workers, "--workers", 0, limits.MAX_WORKERS)
    limits.check_int(args.rounds, "--rounds", 1, limits.MAX_REPEATS)
    limits.check_bake_task_memory(4, int(limits.BUILTIN_VERTICES_PER_DENSITY * args.density) + 1, args.order,
                                  what="--density")
    workers = args.workers or os.cpu_count() or 1
    console = make_console(stderr=True)
    with tempfile.TemporaryDirectory(prefix="prt-bench-bake-") as tmp:
        def config(name: str) -> dict:
            return {"name": name, "run_dir": str(Path(tmp) / name),
                    "character": {"source": "builtin", "density": args.density, "random_poses": args.frames,
                                  "seed": 3},
                    "bake": {"order": args.order, "n_rays": args.rays, "frames_per_task": 4, "seed": 0}}

        cfg1 = config_from_dict(config("single"))
        plan = make_plan(cfg1)
        path, _ = prepare(cfg1, plan)  # store + clustering, not timed
        ds = open_dataset(path)
        ch = plan.character
        V = ch.num_vertices
        console.print(f"built-in character: {V} vertices, {len(ch.faces)} triangles; {args.rays} rays/vertex, "
                      f"{args.frames} frames, order {args.order}")

        # -- raw: every frame's exact rays, prepared beforehand; only the Embree calls are timed --------
        pos_all, nrm_all = ch.skin_mesh(plan.skin)
        fr_all = vertex_frames(nrm_all, plan.skin, ds.cluster, ds.cluster_axis, ds.cluster_bone)
        rays = RaySet.make(args.rays, args.order, V, 0)
        offset = float(ds.attrs["bake"]["ray_offset_world"])
        block = max(1, int(ds.attrs["bake"]["vertex_chunk_rays"]) // args.rays)

        def raw_seconds(f: int) -> tuple[float, int]:
            """Embree time for frame ``f``'s exact rays (scene and rays built untimed)."""
            pos, fr = pos_all[f], fr_all[f]
            scene = RayScene(pos, ch.faces)
            secs, n = 0.0, 0
            for v0 in range(0, V, block):
                v1 = min(V, v0 + block)
                d = np.ascontiguousarray(
                    world_directions(rays.local, rotated_frames(fr[v0:v1], rays.phi[v0:v1])).reshape(-1, 3))
                o = np.empty((args.rays, v1 - v0, 3), np.float32)
                o[:] = (pos[v0:v1] + offset * fr[v0:v1, 2]).astype(np.float32)
                o = o.reshape(-1, 3)
                t0 = time.perf_counter()
                scene.occluded(o, d)
                secs += time.perf_counter() - t0
                n += len(o)
            return secs, n

        # -- raw vs single-process bake, paired block by block (robust to a shared, drifting machine) --
        # BLAS single-threaded as in the bake tasks: idle OpenBLAS threads spin and would slow the raw trace
        limits = threadpool_limits(limits=1)
        tasks = block_tasks(path, plan)
        bake_block(tasks[0])  # warm-up: builds the per-process context (character, clusters, ray set)
        raw_s = bake_s = 0.0
        n_rays = n_frames = 0
        block_ratios = []
        for _ in range(args.rounds):
            for task in tasks:
                r_s = 0.0
                for f in range(task.f0, task.f1):
                    secs, n = raw_seconds(f)
                    r_s += secs
                    n_rays += n
                t0 = time.perf_counter()
                bake_block(task)  # skin, frames, rays, trace, project, write the block's chunks + done
                b_s = time.perf_counter() - t0
                raw_s += r_s
                bake_s += b_s
                block_ratios.append(r_s / b_s)
                n_frames += task.f1 - task.f0
        limits.restore_original_limits()
        raw_rps = n_rays / raw_s
        single_rps = n_rays / bake_s
        single_fps = n_frames / bake_s
        ratio = float(np.median(block_ratios))  # per-block pairs: robust to load bursts on a shared machine

        # -- pool: all cores, worker start-up included -------------------------------------------------
        pooled = run_bake(config_from_dict(config("pool")), workers=workers, progress=False)

    result = {
        "vertices": V, "rays_per_vertex": args.rays, "order": args.order, "frames": args.frames,
        "raw_rays_per_s": raw_rps, "rays_per_s": single_rps, "ratio": ratio, "ratio_of_totals": single_rps / raw_rps,
        "single_frames_per_s": single_fps,
        "workers": workers, "frames_per_s": pooled.frames_per_s, "pool_rays_per_s": pooled.rays_per_s,
        "pool_vs_raw_per_core": pooled.rays_per_s / (raw_rps * workers),
    }
    if args.json:
        print(json.dumps(result, indent=2, sort_keys=True))
    else:
        console.print(f"raw embreex occlusion (1 process): {raw_rps / 1e6:8.2f} Mrays/s")
        console.print(f"bake end-to-end     (1 process): {single_rps / 1e6:8.2f} Mrays/s  "
                      f"{single_fps:6.2f} frames/s   ratio {ratio:.3f}")
        console.print(f"bake end-to-end ({workers} processes): {pooled.rays_per_s / 1e6:8.2f} Mrays/s  "
                      f"{pooled.frames_per_s:6.2f} frames/s   (vs {workers} x raw: "
                      f"{result['pool_vs_raw_per_core']:.3f}, start-up included)")
    return 0

"""``prt bench sg``: seed 004's per-frame cost (voxelise + cone trace + SG shade) vs Embree tracing the same
visibility, side by side, at two voxel grid sizes.

On the built-in character (``--density``; 0.25 ~ 2.9k vertices, 1.0 ~ 11.7k) posed by frames of a clip, for each
grid size and frame, alternately:

* ``sg``: :meth:`prt_torch.vct.renderer.SGVCTRenderer.radiance` for the BRDFs (``lambert,phong``) under the sun
  lighting of ``prt compare --light sun`` (the light fit is done once beforehand and reported, not timed):
  voxelisation, cone tracing (7 sub-cones per lobe, 1 per peak), SG shading;
* ``embree``: the same visibility by rays: the scene built from the posed mesh and ``--rays`` occlusion rays per
  vertex over the hemisphere (stratified, the bake's density), plus one ray per vertex toward each peak.

``ratio = embree ms / sg ms`` (median over frames; > 1: cone tracing is the faster way to this frame's
visibility). Also reported: the Lambert-lobe visibility of the cones vs Embree's cosine-weighted visibility
(mean absolute error), the accuracy bought at that cost. torch threads: ``--threads`` (Embree uses its own).
"""

from __future__ import annotations

import argparse
import json
import time

HELP = "SG + voxel cone tracing ms/frame (voxelise, trace, shade) vs Embree tracing the same visibility."


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--density", type=float, default=0.25, help="built-in character density (0.25: ~2.9k "
                                                                    "vertices; 1.0: ~11.7k)")
    parser.add_argument("--grids", default="64,128", help="voxel grid sizes, comma-separated (default 64,128)")
    parser.add_argument("--frames", type=int, default=3, help="frames of the clip measured (default 3)")
    parser.add_argument("--clip", default="squat", help="built-in clip posed (default squat)")
    parser.add_argument("--rays", type=int, default=256, help="Embree rays per vertex (default 256)")
    parser.add_argument("--brdfs", default="lambert,phong", help="BRDFs shaded (default lambert,phong)")
    parser.add_argument("--threads", type=int, default=2, help="torch threads (default 2)")
    parser.add_argument("--device", default="cpu", help="torch device of the SG renderer (cpu, cuda)")
    parser.add_argument("--json", action="store_true", help="print one JSON object")


def run(args: argparse.Namespace) -> int:
    import numpy as np
    import torch

    from prt_torch import limits
    from prt_torch.bake.embree import RayScene
    from prt_torch.brdf.rpo import CATALOGUE, builtin_brdf
    from prt_torch.compare.reference import light_spec, spec_envmap
    from prt_torch.errors import PrtError
    from prt_torch.metrics import evenly_spaced_indices
    from prt_torch.progress import make_console
    from prt_torch.rig.builtin import make_character
    from prt_torch.sg.brdf_fit import fit_brdf_sg
    from prt_torch.sg.shading import sg_light_from_env
    from prt_torch.sh.quadrature import hemisphere_directions
    from prt_torch.vct.cones import ConeSet, pack_lobe_cones, tangent_frame
    from prt_torch.vct.renderer import SGVCTRenderer
    from prt_torch.vct.visibility import lobe_visibility

    limits.check_float(args.density, "--density", limits.MIN_DENSITY, limits.MAX_DENSITY)
    limits.check_int(args.frames, "--frames", 1, limits.MAX_FRAMES)
    limits.check_int(args.rays, "--rays", 1, limits.MAX_RAYS)
    limits.check_int(args.threads, "--threads", 1, limits.MAX_THREADS)
    grids = _ints(args.grids, "--grids")
    brdf_names = [b.strip() for b in args.brdfs.split(",") if b.strip()]
    for b in brdf_names:
        if b not in CATALOGUE:
            raise PrtError(f"--brdfs: unknown BRDF {b!r}: expected {', '.join(CATALOGUE)}")
    if args.device.startswith("cuda") and not torch.cuda.is_available():
        raise PrtError("--device cuda: no CUDA device")
    torch.set_num_threads(args.threads)
    console = make_console(stderr=True)

    ch = make_character(args.density)
    if args.clip not in ch.clips:
        raise PrtError(f"--clip: unknown clip {args.clip!r}; available: {sorted(ch.clips)}")
    poses = ch.pose(args.clip)
    idx = evenly_spaced_indices(poses.num_frames, args.frames)
    pos_all, nrm_all = ch.skin_mesh(poses.skin[idx])
    nrm_all = nrm_all / np.linalg.norm(nrm_all, axis=-1, keepdims=True)
    faces = np.asarray(ch.faces)
    eye = np.array([0.0, -4.0, 1.2])
    t0 = time.perf_counter()
    light = sg_light_from_env(spec_envmap(light_spec("sun")))
    t_light = time.perf_counter() - t0
    brdfs = {b: fit_brdf_sg(builtin_brdf(b)) for b in brdf_names}
    v = ch.num_vertices
    console.print(f"built-in character: {v} vertices, {len(faces)} triangles; {args.frames} frames of "
                  f"{args.clip}; light fit {t_light * 1e3:.0f} ms ({light.source})")
    loc = hemisphere_directions(args.rays, seed=3)
    result: dict = {"n_vertices": v, "n_triangles": int(len(faces)), "frames": int(args.frames),
                    "embree_rays_per_vertex": args.rays, "light_fit_ms": t_light * 1e3, "light": light.source,
                    "brdfs": brdf_names, "device": args.device, "torch_threads": args.threads, "grids": {}}
    for r in grids:
        rend = SGVCTRenderer(faces, brdfs, light, r, peaks=True, device=args.device)
        rend.radiance(pos_all[0], nrm_all[0], eye)  # warm-up
        sg, emb, parts, mae = [], [], [], []
        for f in range(args.frames):
            pos, nrm = pos_all[f].astype(np.float32), nrm_all[f].astype(np.float32)
            t0 = time.perf_counter()
            rend.radiance(pos, nrm, eye)
            sg.append(time.perf_counter() - t0)
            t = rend.times
            parts.append((t.voxelize, t.trace, t.shade))
            # Embree: the same visibility by rays (hemisphere + one ray per peak), scene build included
            t0 = time.perf_counter()
            t1, t2 = (x.numpy() for x in tangent_frame(torch.tensor(nrm, dtype=torch.float64)))
            world = loc[:, None, 0, None] * t1 + loc[:, None, 1, None] * t2 + loc[:, None, 2, None] * nrm
            scene = RayScene(pos, faces)
            org = np.broadcast_to(pos + 1e-3 * nrm, world.shape).reshape(-1, 3).astype(np.float32)
            occ = scene.occluded(org, world.reshape(-1, 3).astype(np.float32)).reshape(args.rays, v)
            for d in light.peak_dirs.numpy():
                scene.occluded(pos + 1e-3 * nrm, np.broadcast_to(d, (v, 3)).astype(np.float32))
            emb.append(time.perf_counter() - t0)
            ref = ((~occ) * loc[:, 2, None]).sum(0) / loc[:, 2].sum()
            pt, nt = torch.tensor(pos), torch.tensor(nrm)
            d, h, w = pack_lobe_cones(nt, torch.full((v,), 2.133), 7)
            cones = ConeSet(d, h, w, torch.zeros(7, dtype=torch.long))
            vis = lobe_visibility(rend.tracer.trace(rend.tracer.voxelize(pt), pt, nt, cones), cones, 1)[:, 0]
            mae.append(float(np.abs(vis.numpy() - ref).mean()))
        sg_ms, emb_ms = np.median(sg) * 1e3, np.median(emb) * 1e3
        p = np.median(np.asarray(parts), axis=0) * 1e3
        result["grids"][str(r)] = {"sg_ms": sg_ms, "voxelize_ms": p[0], "trace_ms": p[1], "shade_ms": p[2],
                                   "embree_ms": emb_ms, "ratio_embree_over_sg": emb_ms / sg_ms,
                                   "lambert_visibility_mae_vs_embree": float(np.mean(mae))}
        console.print(f"grid {r}^3: sg {sg_ms:.0f} ms/frame (voxelise {p[0]:.0f}, trace {p[1]:.0f}, shade "
                      f"{p[2]:.0f}) vs Embree {emb_ms:.0f} ms ({args.rays} rays/vertex): ratio "
                      f"{emb_ms / sg_ms:.2f}; Lambert-lobe visibility MAE vs Embree {np.mean(mae):.3f}")
    if args.json:
        print(json.dumps(result, indent=2, default=float))
    return 0


def _ints(text: str, name: str) -> list[int]:
    from prt_torch.errors import PrtError
    from prt_torch.vct.grid import check_resolution

    try:
        out = [int(x) for x in text.split(",") if x.strip()]
    except ValueError:
        raise PrtError(f"{name}: expected comma-separated integers, got {text!r}") from None
    if not out:
        raise PrtError(f"{name}: no grid size given")
    return [check_resolution(x) for x in out]

"""``prt heightfield``: the dynamic height-field visibility generator (seed 003 eq. 4-5) against Embree truth.

For each grid size ``N`` (``--sizes``) and height-field kind (``--kinds``: procedural waves, a deforming
terrain) it animates ``--frames`` frames and, per frame, on the same triangle mesh (``2 (N-1)^2`` triangles):

* **height-field PRT**: :class:`prt_torch.heightfield.HeightFieldVisibility` (max-pyramid horizons, wedge
  tables, z-rotations), timed as the median of ``--repeat`` runs after a warm-up;
* **truth**: the bake's Embree tracer (:func:`prt_torch.heightfield.truth.truth_visibility`, ``--rays`` rays
  per vertex), timed once per frame (scene build included: the mesh deforms every frame);
* **unshadowed**: the unoccluded visibility, for scale.

Both timings are single-threaded by default (``--threads 1``; the bake's Embree tracer is single-threaded
per call). Scores: visibility relative SH error vs truth (:func:`prt_torch.metrics.vis_rel_err`, pooled over
frames), vertex radiance relative RMSE and image PSNR (diffuse = ``lambert``, glossy = ``phong``) on the
shipping path (:mod:`prt_torch.scoring`: the shipped RPOs through ``shade_rpo``, the player's sky
lighting on the ``lobes`` path, the player's renderer and tone map fixed from the truth, PSNR over the
pixels the mesh covers). The camera is the player's orbit rule (:func:`prt_torch.player.player.camera_eye`)
at a higher elevation (:data:`CAMERA_ELEVATION`) and closer (:data:`CAMERA_RADIUS` of the diagonal) so the
terrain's shadows fill the frame.

Writes ``OUT/heightfield.json``, ``OUT/heightfield.md`` and ``OUT/<kind>_<N>.png`` (row 1: truth | height-field PRT |
unshadowed, diffuse; row 2: 4 x |difference| to the truth; rows 3-4: the same, glossy).
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from prt_torch.conventions import BELOW_HORIZON

HELP = "Dynamic height-field visibility (max pyramid + SH wedges) vs Embree: error, image PSNR, ms per frame."

#: camera of the report images: the player's orbit at this elevation (radians) and this fraction of its distance
CAMERA_ELEVATION, CAMERA_RADIUS = 0.6, 0.55
#: report files in ``--out`` (a report directory, not a run directory)
REPORT_JSON, REPORT_MD = "heightfield.json", "heightfield.md"
#: images of the report: (name, label) in strip order
METHODS = (("truth", "Embree truth"), ("hf", "height-field PRT"), ("unshadowed", "unshadowed"))


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--sizes", default="128,256,512", help="grid sizes N, comma-separated (default 128,256,512)")
    parser.add_argument("--frames", type=int, default=2, help="animation frames per size and kind (default 2)")
    parser.add_argument("--kinds", default="waves,terrain", help="height fields: waves, terrain (default both)")
    parser.add_argument("--wedges", type=int, default=16, help="azimuthal wedges n (default 16)")
    parser.add_argument("--order", type=int, default=4, help="SH order (default 4)")
    parser.add_argument("--stride", type=int, default=0,
                        help="horizon search stride (0 = auto: 1 up to 256^2, N // 256 above)")
    parser.add_argument("--rays", type=int, default=512, help="Embree rays per vertex of the truth (default 512)")
    parser.add_argument("--repeat", type=int, default=3, help="timed runs of the height-field generator (default 3)")
    parser.add_argument("--threads", type=int, default=1, help="torch intra-op threads (default 1)")
    parser.add_argument("--below-horizon", default="one", choices=BELOW_HORIZON[::-1],
                        help="visibility below the horizon (the bake's convention; default one)")
    parser.add_argument("--out", default="runs/heightfield", help="report directory (default runs/heightfield)")
    parser.add_argument("--json", action="store_true", help="print the JSON report instead of the table")


def auto_stride(n: int) -> int:
    """The default horizon stride: every vertex up to 256^2, then ``N // 256`` (the paper sub-samples too)."""
    return max(1, n // 256)


def _parse_list(text: str, name: str) -> list[str]:
    from prt_torch.errors import check

    items = [t.strip() for t in str(text).split(",") if t.strip()]
    check(len(items) > 0, f"{name}: expected a comma-separated list, got {text!r}")
    return items


def _table(res: dict[str, Any]) -> str:
    head = ("| N | triangles | stride | vis rel err HF (unshadowed) | PSNR diffuse HF (unsh.) dB | "
            "PSNR glossy HF (unsh.) dB | HF ms | Embree ms | Embree / HF | HF table bytes |")
    lines = [head, "|" + " --- |" * 10]
    for key, s in res["sizes"].items():
        m = s["summary"]
        lines.append(
            f"| {key} | {s['triangles']} | {s['stride']} | "
            f"{m['vis_rel_err']:.4f} ({m['vis_rel_err_unshadowed']:.4f}) | "
            f"{m['psnr_image_diffuse']:.2f} ({m['psnr_image_diffuse_unshadowed']:.2f}) | "
            f"{m['psnr_image_glossy']:.2f} ({m['psnr_image_glossy_unshadowed']:.2f}) | {m['ms_per_frame']:.1f} | "
            f"{m['embree_ms_per_frame']:.0f} | {m['speedup']:.1f}x | {s['bytes']['table']} |")
    return "\n".join(lines) + "\n"


def run(args: argparse.Namespace) -> int:
    import json
    import statistics
    import time

    import numpy as np
    import torch
    from threadpoolctl import threadpool_limits

    from prt_torch import limits
    from prt_torch.bake.trace import RaySet
    from prt_torch.errors import check
    from prt_torch.heightfield.horizon import check_wedges
    from prt_torch.heightfield.surface import KINDS, check_grid_size, grid_faces, make_frame, make_generator
    from prt_torch.heightfield.truth import truth_visibility
    from prt_torch.heightfield.visibility import HeightFieldVisibility
    from prt_torch.io import atomic_write_json, atomic_write_text
    from prt_torch.player.player import camera_eye, camera_target
    from prt_torch.scoring.images import Camera, ImageRenderer
    from prt_torch.scoring.lighting import PLAYER_LIGHT, shipping_lights, unshadowed_visibility
    from prt_torch.scoring.rpos import DIFFUSE, GLOSSY, shipping_rpos
    from prt_torch.scoring.shading import ShippingShader
    from prt_torch.scoring.statistics import ImageStats, RadianceStats
    from prt_torch.scoring.strips import abs_diff_image, image_strip, write_png
    from prt_torch.sh.product import MAX_PRODUCT_ORDER

    sizes = []
    for t in _parse_list(args.sizes, "--sizes"):
        check(t.isdigit(), f"--sizes: {t!r} is not a positive integer")
        sizes.append(check_grid_size(int(t)))
    kinds = _parse_list(args.kinds, "--kinds")
    for k in kinds:
        check(k in KINDS, f"--kinds: unknown height field {k!r}: expected some of {list(KINDS)}")
    limits.check_int(args.frames, "--frames", 1, 1000)
    check_wedges(args.wedges)
    limits.check_int(args.order, "--order", 2, MAX_PRODUCT_ORDER)
    limits.check_int(args.stride, "--stride", 0, 64)
    limits.check_int(args.rays, "--rays", 16, limits.MAX_RAYS)
    limits.check_int(args.repeat, "--repeat", 1, 100)
    limits.check_int(args.threads, "--threads", 1, 256)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    torch.set_num_threads(args.threads)
    order = args.order
    lights = shipping_lights(order, names=[PLAYER_LIGHT])
    rpos = shipping_rpos(order)
    unocc = unshadowed_visibility(order, args.below_horizon)
    times = [0.25 + 0.6 * i for i in range(args.frames)]
    results: dict[str, Any] = {
        "settings": {"sizes": sizes, "kinds": kinds, "frames": args.frames, "times_s": times, "wedges": args.wedges,
                     "order": order, "rays": args.rays, "threads": args.threads, "repeat": args.repeat,
                     "below_horizon": args.below_horizon, "lighting": PLAYER_LIGHT, "lighting_path": "lobes",
                     "brdfs": {"diffuse": DIFFUSE, "glossy": GLOSSY},
                     "timed": "hf: HeightFieldVisibility(heights, frames) (pyramid, horizons, wedge sums, rotation "
                              "into the vertex frames), median of --repeat; embree: bake.trace.trace_frame (scene "
                              "build, rays, SH projection), once per frame; both get the same mesh and frames, whose "
                              "generation is not timed"},
        "sizes": {},
    }
    models: dict[int, HeightFieldVisibility] = {}
    with threadpool_limits(limits=args.threads):
        for n in sizes:
            stride = args.stride or auto_stride(n)
            if stride not in models:
                models[stride] = HeightFieldVisibility(order, args.wedges, stride=stride,
                                                       below_horizon=args.below_horizon)
            model = models[stride]
            faces = grid_faces(n)
            rest = make_frame(np.zeros((n, n)), faces=faces).positions
            center, diag = camera_target(rest)
            eye = camera_eye(center, CAMERA_RADIUS * diag, elevation=CAMERA_ELEVATION)
            camera = Camera(np.asarray(eye, np.float64), np.asarray(center, np.float64))
            shader = ShippingShader(lights, rpos, camera.eye, paths=("lobes",))
            rays = RaySet.make(args.rays, order, n * n, 0, args.below_horizon)
            per_kind: dict[str, Any] = {}
            with ImageRenderer(rest, faces, camera) as renderer:
                for kind in kinds:
                    gen = make_generator(kind, n)
                    num = {"hf": 0.0, "unshadowed": 0.0}
                    den = 0.0
                    rad = {(m, b): RadianceStats() for m in ("hf", "unshadowed") for b in rpos}
                    img = {(m, b): ImageStats() for m in ("hf", "unshadowed") for b in rpos}
                    hf_ms, embree_ms = [], []
                    for fi, t in enumerate(times):
                        frame = make_frame(gen(t), faces=faces)
                        if fi == 0:
                            model(frame.heights, frame.frames)  # warm-up (allocations, caches)
                        runs = []
                        for _ in range(args.repeat):
                            t0 = time.perf_counter()
                            with torch.no_grad():
                                hf = model(frame.heights, frame.frames)
                            runs.append(time.perf_counter() - t0)
                        hf_ms.append(1e3 * statistics.median(runs))
                        hf = hf.numpy()
                        t0 = time.perf_counter()
                        truth = truth_visibility(frame, order, rays=rays)
                        embree_ms.append(1e3 * (time.perf_counter() - t0))
                        den += float((truth.astype(np.float64) ** 2).sum())
                        num["hf"] += float(((hf - truth).astype(np.float64) ** 2).sum())
                        num["unshadowed"] += float(((unocc - truth).astype(np.float64) ** 2).sum())
                        shaded = shader.shade_chunk({"truth": truth[None], "hf": hf[None], "unshadowed": unocc},
                                                    frame.frames[None], frame.positions[None])
                        strip_rows = []
                        for b in rpos:
                            radiance = {m: shaded[(PLAYER_LIGHT, b, "lobes")][m][0] for m, _ in METHODS}
                            fimg = renderer.frame_images(frame.positions, radiance, "truth")
                            for m in ("hf", "unshadowed"):
                                rad[(m, b)].add(radiance[m], radiance["truth"])
                                img[(m, b)].add(*fimg.sse[m])
                            if fi == 0:
                                ims = [fimg.images[m] for m, _ in METHODS]
                                diffs = [None] + [abs_diff_image(fimg.images[m], fimg.images["truth"])
                                                  for m, _ in METHODS[1:]]
                                strip_rows.append(image_strip(
                                    ims, [f"{lab} ({b})" for _, lab in METHODS], diffs,
                                    ["", "4 x |HF - truth|", "4 x |unshadowed - truth|"]))
                        if strip_rows:
                            write_png(out / f"{kind}_{n}.png", np.concatenate(strip_rows, axis=0))
                    entry: dict[str, Any] = {
                        "vis_rel_err": float(np.sqrt(num["hf"] / den)),
                        "vis_rel_err_unshadowed": float(np.sqrt(num["unshadowed"] / den)),
                        "ms_per_frame": float(statistics.median(hf_ms)),
                        "embree_ms_per_frame": float(statistics.median(embree_ms)),
                        "hf_ms_frames": hf_ms, "embree_ms_frames": embree_ms,
                        "image": f"{kind}_{n}.png",
                    }
                    for m in ("hf", "unshadowed"):
                        suffix = "" if m == "hf" else "_unshadowed"
                        for key, b in (("diffuse", DIFFUSE), ("glossy", GLOSSY)):
                            entry[f"psnr_image_{key}{suffix}"] = img[(m, b)].psnr
                            entry[f"radiance_rel_rmse_{key}{suffix}"] = rad[(m, b)].rel_rmse
                    entry["speedup"] = entry["embree_ms_per_frame"] / entry["ms_per_frame"]
                    per_kind[kind] = entry
            keys = [k for k in next(iter(per_kind.values())) if isinstance(next(iter(per_kind.values()))[k], float)]
            summary = {k: float(np.mean([e[k] for e in per_kind.values()])) for k in keys}
            summary["ms_per_frame"] = float(np.median([x for e in per_kind.values() for x in e["hf_ms_frames"]]))
            summary["embree_ms_per_frame"] = float(np.median([x for e in per_kind.values()
                                                              for x in e["embree_ms_frames"]]))
            summary["speedup"] = summary["embree_ms_per_frame"] / summary["ms_per_frame"]
            c = order * order
            results["sizes"][str(n)] = {
                "n": n, "vertices": n * n, "triangles": int(faces.shape[0]), "stride": stride,
                "kinds": per_kind, "summary": summary,
                "bytes": {"table": model.n_bytes, "heights": 4 * n * n, "visibility": 4 * c * n * n,
                          "embree_rays_per_frame": args.rays * n * n},
            }
            atomic_write_json(out / REPORT_JSON, results)  # after every size: partial results survive
    table = _table(results)
    atomic_write_text(out / REPORT_MD, "# Dynamic height field vs Embree\n\n" + table)
    if args.json:
        print(json.dumps(results, indent=2))
    else:
        print(table, end="")
        print(f"report: {out}")
    return 0

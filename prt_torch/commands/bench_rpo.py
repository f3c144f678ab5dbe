"""``prt bench rpo [RUN]``: the RPO's term count ``k`` and factorisation order against the Monte-Carlo reference.

For every catalogue BRDF (``--brdfs``), every ``k`` (``--terms``) and both factorisation orders (``--factor-orders``,
:mod:`prt_torch.brdf.factor`), one RPO is built (:func:`prt_torch.brdf.rpo.build_rpo`) and shades the SAME baked
ray-traced visibility of the run's held-out frames (``sh_truth``'s, so that only the RPO differs between rows)
under the same lighting (``--light``, default ``smooth``: the procedural sky without its sun, where the RPO's error
is not hidden by a peak light) on the shipping shading path (:class:`prt_torch.scoring.shading.ShippingShader`).
Each row is scored against :func:`prt_torch.compare.reference.reference_pair` (Embree visibility, the analytic
BRDF, no SH anywhere) on ``--frames`` frames:

* ``psnr_db``: image PSNR at the player's camera, one tone map per frame from the reference (``prt compare``'s
  rule: :meth:`prt_torch.scoring.images.ImageRenderer.frame_images`);
* ``rel_err``: vertex radiance relative RMSE over the camera-facing vertices;
* ``op_err``: the RPO's relative error against the untruncated order-``n`` operator
  (:func:`prt_torch.brdf.factor.operator_error`; 0 for ``after`` at ``k >= C``), and ``rel_err_op`` the vertex
  radiance relative RMSE against that operator's shading of the same frames (the RPO's own share of the error,
  which the reference comparison mixes with the SH truncation of the light and the visibility);
* ``bytes``: the RPO file (``u``, ``w``, tint: ``RPO.save``) and ``m_bytes`` the product matrices ``M`` the
  shading reads (``k C^2`` float32);
* ``ms``: median ms per frame of the run's own frame path with that RPO - the compiled decode + shade pass
  (:mod:`prt_torch.player.compiled`) when the export ships it, else the torch shading of the same frame - all
  rows interleaved frame by frame, ``--repeats`` rounds (shared machine: compare rows within one run only).

The noise row (estimate b vs estimate a of the reference) bounds what any row can reach, and the ``after`` row at
``k = C`` is the untruncated operator: what is left there is the SH truncation of the light and visibility.
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

HELP = ("RPO term count k and factorisation order (before / after the SH projection) per catalogue BRDF vs the "
        "Monte-Carlo reference: image PSNR, bytes, ms per frame.")

DEFAULT_RUN = "runs/demo"
DEFAULT_TERM_LIST = "4,8,16,32"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("run", nargs="?", default=DEFAULT_RUN, help=f"trained, exported run (default {DEFAULT_RUN})")
    parser.add_argument("--brdfs", default="phong,blinn,ggx,ward,lambert", help="comma-separated catalogue BRDFs")
    parser.add_argument("--terms", default=DEFAULT_TERM_LIST, help=f"comma-separated k (default {DEFAULT_TERM_LIST})")
    parser.add_argument("--factor-orders", default="before,after", help="comma-separated: before, after")
    parser.add_argument("--frames", type=int, default=4, help="held-out frames scored (evenly spaced, default 4)")
    parser.add_argument("--reference-rays", type=int, default=1024,
                        help="rays per vertex of each of the two reference estimates (default 1024: its noise ~50 dB "
                             "on the demo, far below the rows' differences)")
    parser.add_argument("--light", default="smooth", choices=["smooth", "sky", "sun"],
                        help="prt compare's --light (default smooth: the sky without its sun)")
    parser.add_argument("--repeats", type=int, default=15, help="timing rounds (default 15)")
    parser.add_argument("--threads", type=int, default=2, help="threads of the timed frame path (default 2)")
    parser.add_argument("--json", action="store_true", help="print the JSON")


def _names(text: str, what: str, allowed: tuple[str, ...]) -> list[str]:
    from prt_torch.errors import PrtError

    out = [t.strip() for t in text.split(",") if t.strip()]
    if not out:
        raise PrtError(f"--{what}: empty list")
    bad = [t for t in out if t not in allowed]
    if bad:
        raise PrtError(f"--{what}: unknown {bad[0]!r}, expected some of {', '.join(allowed)}")
    return list(dict.fromkeys(out))


def _terms(text: str) -> list[int]:
    from prt_torch.errors import PrtError

    try:
        ks = sorted({int(t) for t in text.split(",") if t.strip()})
    except ValueError:
        raise PrtError(f"--terms: expected comma-separated integers, got {text!r}") from None
    if not ks or ks[0] < 1 or ks[-1] > 256:
        raise PrtError(f"--terms: each k must be in 1..256, got {text!r}")
    return ks


def _timer(run_dir: str, threads: int, fs: Any, order: int) -> tuple[Any, str]:
    """``(time_one(rpo) -> seconds, label)``: one held-out frame of the run's compiled frame path (any ``k`` plays
    there) with an RPO; a run without it is a one-line error."""
    from prt_torch.errors import MissingArtifact, check
    from prt_torch.player.bundle import RPOTensors
    from prt_torch.player.player import Player
    from prt_torch.rundir import RunDir

    run = RunDir(run_dir)
    meta = json.loads(run.export_json.read_text()) if run.export_json.is_file() else {}
    if not isinstance(meta.get("compiled"), dict):
        raise MissingArtifact(f"{run_dir}: the export has no compiled frame path (where any k plays): run "
                              f"`prt export {run_dir} --force`")
    check(fs.local is not None, f"{run_dir}: the held-out frames carry no pose (a deformable subject)")
    player = Player(run_dir, brdf="phong", graph="compiled", threads=threads)  # a catalogue BRDF: nothing built
    state = player.pose(fs.local[:1])

    def one(rpo: Any) -> float:
        player.rpo = RPOTensors(rpo.name, order, rpo.M, rpo.w, rpo.tint, rpo.u)
        t0 = time.perf_counter()
        player.shade(state)
        return time.perf_counter() - t0

    return one, "compiled decode + shade pass of one frame (the player's default CPU frame path)"


def bench(run_dir: str, brdfs: list[str], terms: list[int], orders: list[str], n_frames: int = 4,
          reference_rays: int = 1024, light: str = "smooth", repeats: int = 15, threads: int = 2,
          log: Any = None) -> dict[str, Any]:
    """The sweep (module docstring); returns the JSON."""
    from prt_torch.brdf.factor import DEFAULT_FACTOR_ORDER, DEFAULT_TERMS
    from prt_torch.brdf.rpo import build_rpo, builtin_brdf
    from prt_torch.compare.reference import compare_lights, front_facing, reference_pair
    from prt_torch.compare.run import heldout_frames, load_compare_run
    from prt_torch.errors import check
    from prt_torch.player.material import surface_albedo
    from prt_torch.scoring.images import ImageRenderer, player_camera
    from prt_torch.scoring.shading import ShippingShader
    from prt_torch.scoring.statistics import ImageStats, RadianceStats, image_sse

    note = log or (lambda s: None)
    ctx = load_compare_run(run_dir)
    check(ctx.character.num_vertices == ctx.n_vertices, "character and dataset disagree")
    fs = heldout_frames(ctx, n_frames)
    check(fs.baked_visibility is not None, f"{run_dir}: the held-out frames carry no baked visibility")
    order = ctx.order
    c = order * order
    lights = compare_lights(light, None, order, peaks=0)
    camera = player_camera(ctx.character)
    albedo = surface_albedo(ctx.character)
    sa = albedo.apply
    faces = np.asarray(ctx.character.faces)
    offset = float(ctx.bake["ray_offset_world"])

    # -- the RPOs ------------------------------------------------------------------------------------------------
    rows: dict[str, dict[str, Any]] = {}
    rpos: dict[str, Any] = {}
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="prt_bench_rpo_") as tmp:
        for b in brdfs:
            brdf = builtin_brdf(b)
            for fo in orders:
                for k in terms:
                    key = f"{b}/{fo}/k{k}"
                    rpo = build_rpo(brdf, order, k, name=b, factor_order=fo, quiet=True)
                    nbytes = rpo.save(Path(tmp) / f"{b}_{fo}_{k}.npz")
                    rpos[key] = rpo
                    rows[key] = {"brdf": b, "factor_order": fo, "k": k, "op_err": rpo.meta["operator_error"],
                                 "bytes": int(nbytes), "m_bytes": int(rpo.M.nbytes), "exact": fo == "after" and k >= c}
        # each BRDF's untruncated order-n operator ("after" at k = C: exact), the reference of the rel_err_op column
        exact = {b: build_rpo(builtin_brdf(b), order, c, name=b, factor_order="after") for b in brdfs}
    note(f"built {len(rpos)} RPOs (order {order}) in {time.perf_counter() - t0:.0f} s")

    # -- timing: all rows interleaved, frame by frame ------------------------------------------------------------
    time_one, runtime = _timer(run_dir, threads, fs, order)
    for r in rpos.values():
        time_one(r)  # warm-up (numba compilation, the compiled path's per-RPO tables)
    secs: dict[str, list[float]] = {key: [] for key in rpos}
    for _ in range(max(1, repeats)):
        for key, r in rpos.items():
            secs[key].append(time_one(r))
    for key in rows:
        rows[key]["ms"] = float(np.median(secs[key]) * 1e3)
    note(f"timed {len(rpos)} RPOs x {repeats} rounds on the {runtime}")

    # -- shading and the reference -------------------------------------------------------------------------------
    shader = ShippingShader({"light": lights.lighting}, rpos, camera.eye, paths=("lobes",))
    shaded = shader.shade_all({"truth": fs.baked_visibility}, fs.frames, fs.positions)
    untrunc = ShippingShader({"light": lights.lighting}, exact, camera.eye, paths=("lobes",)).shade_all(
        {"truth": fs.baked_visibility}, fs.frames, fs.positions)
    rad_op = {key: RadianceStats() for key in rpos}
    img = {key: ImageStats() for key in rpos}
    rad = {key: RadianceStats() for key in rpos}
    noise_img = {b: ImageStats() for b in brdfs}
    noise_rad = {b: RadianceStats() for b in brdfs}
    analytic = {b: builtin_brdf(b) for b in brdfs}
    renderer = ImageRenderer(ctx.character.rest_vertices, faces, camera, albedo=albedo)
    t0 = time.perf_counter()
    try:
        for f in range(fs.n_frames):
            pos = fs.positions[f]
            mask = renderer.mask(pos)
            pair = reference_pair(pos, fs.frames[f], faces, camera.eye, lights.reference, analytic, reference_rays,
                                  offset)
            mean = pair.mean
            front = front_facing(pos, fs.frames[f], camera.eye)
            for b in brdfs:
                keys = [key for key in rpos if rows[key]["brdf"] == b]
                cand = {"reference": mean[b], "a": pair.a[b], "b": pair.b[b],
                        **{key: shaded[("light", key, "lobes")]["truth"][f] * front[:, None] for key in keys}}
                fi = renderer.frame_images(pos, cand, "reference", mask=mask)
                for key in keys:
                    img[key].add(*fi.sse[key])
                    rad[key].add(sa(cand[key])[front], sa(mean[b])[front])
                    rad_op[key].add(sa(cand[key])[front], sa(untrunc[("light", b, "lobes")]["truth"][f])[front])
                noise_img[b].add(*image_sse(fi.images["b"], fi.images["a"], fi.mask))
                noise_rad[b].add(sa(pair.b[b])[front], sa(pair.a[b])[front])
    finally:
        renderer.close()
    note(f"reference: {fs.n_frames} frames x 2 estimates x {reference_rays} rays in {time.perf_counter() - t0:.0f} s")
    for key in rows:
        rows[key]["psnr_db"] = img[key].psnr
        rows[key]["rel_err"] = rad[key].rel_rmse
        rows[key]["rel_err_op"] = rad_op[key].rel_rmse
    return {
        "run": str(run_dir), "sh_order": order, "n_vertices": ctx.n_vertices, "frames": fs.n_frames,
        "light": lights.lighting.source, "reference_rays": reference_rays, "timing": runtime,
        "defaults": {"k": DEFAULT_TERMS, "factor_order": DEFAULT_FACTOR_ORDER},
        "noise": {b: {"psnr_db": noise_img[b].psnr, "rel_err": noise_rad[b].rel_rmse} for b in brdfs},
        "rows": list(rows.values()),
    }


def table(result: dict[str, Any]) -> str:
    """Markdown table of :func:`bench`'s rows, grouped by BRDF, one noise line per BRDF."""
    lines = ["| BRDF | order | k | op. err | rel. err vs untruncated | rel. err vs ref | image PSNR dB vs ref | "
             "RPO file B | M bytes | ms/frame |", "|---|---|---|---|---|---|---|---|---|---|"]
    for b, noise in result["noise"].items():
        for r in (r for r in result["rows"] if r["brdf"] == b):
            mark = " (exact)" if r["exact"] else ""
            lines.append(f"| {b} | {r['factor_order']} | {r['k']}{mark} | {r['op_err']:.4f} | {r['rel_err_op']:.4f} | "
                         f"{r['rel_err']:.4f} | "
                         f"{r['psnr_db']:.2f} | {r['bytes']} | {r['m_bytes']} | {r['ms']:.2f} |")
        lines.append(f"| {b} | MC noise (a vs b) | | | | {noise['rel_err']:.4f} | {noise['psnr_db']:.2f} | | | |")
    return "\n".join(lines)


def run(args: argparse.Namespace) -> int:
    from prt_torch import limits
    from prt_torch.brdf.factor import FACTOR_ORDERS
    from prt_torch.brdf.rpo import CATALOGUE
    from prt_torch.commands import _validate as V
    from prt_torch.progress import make_console

    brdfs = _names(args.brdfs, "brdfs", tuple(CATALOGUE))
    orders = _names(args.factor_orders, "factor-orders", FACTOR_ORDERS)
    terms = _terms(args.terms)
    limits.check_int(args.frames, "--frames", 1, limits.MAX_FRAMES)
    limits.check_int(args.reference_rays, "--reference-rays", 1, limits.MAX_RAYS)
    limits.check_int(args.repeats, "--repeats", 1, 1000)
    limits.check_int(args.threads, "--threads", 1, limits.MAX_THREADS)
    V.input_dir(args.run, "run directory")
    console = make_console(stderr=True)
    result = bench(args.run, brdfs, terms, orders, args.frames, args.reference_rays, args.light, args.repeats,
                   args.threads, log=console.log)
    if args.json:
        print(json.dumps(result, indent=2, default=float))
        return 0
    print(f"{result['run']}: order {result['sh_order']}, {result['n_vertices']} vertices, {result['frames']} held-out "
          f"frames, {result['light']}, reference 2 x {result['reference_rays']} rays; ms: {result['timing']}; "
          f"defaults k={result['defaults']['k']} {result['defaults']['factor_order']}")
    print(table(result))
    return 0

"""The ``prt compare`` harness: pose frames, run every method round-robin, score on the shipping path, write.

See :mod:`prt_torch.compare` for the JSON schema and :mod:`prt_torch.compare.methods` for the methods.
"""

from __future__ import annotations

import html
import json
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from prt_torch import metrics as M
from prt_torch.bake.deformable import is_deformable
from prt_torch.bake.store import recorded_fps
from prt_torch.compare.methods import METHODS, CompareRun, FrameSet, MethodBase, RadianceRequest, resolve
from prt_torch.compare.reference import front_facing, reference_light, reference_pair
from prt_torch.errors import PrtError, check
from prt_torch.io import atomic_path, atomic_write_json, atomic_write_text
from prt_torch.rundir import RunDir
from prt_torch.scoring.images import ImageRenderer, player_camera
from prt_torch.scoring.rpos import DIFFUSE, GLOSSY, player_brdfs
from prt_torch.scoring.sampling import evenly_spaced
from prt_torch.scoring.shading import ShippingShader
from prt_torch.scoring.statistics import ImageStats, RadianceStats
from prt_torch.scoring.strips import abs_diff_image, image_strip, write_png

TRUTH = "sh_truth"
REFERENCE = "reference"
#: the BRDF of the image strip for a character without its own material (one with its own: ``material``, what
#: the player plays; :func:`strip_brdf`)
STRIP_BRDF = DIFFUSE
TAGS = {DIFFUSE: "diffuse", GLOSSY: "glossy"}


def load_compare_run(run_dir: str | Path | RunDir, dataset: str | Path | None = None, threads: int = 2) -> CompareRun:
    """The :class:`CompareRun` of a trained run (its dataset and character; the export when present)."""
    run = RunDir.of(run_dir).require()
    meta = run.model_meta()
    ds = run.resolve_dataset(meta, dataset)
    character = ds.character()
    check(character.num_vertices == ds.n_vertices,
          f"{ds.path}: {ds.n_vertices} vertices, its character {character.num_vertices}")
    check(len(ds.faces) > 0, f"{ds.path}: the dataset has no faces to trace")
    bake = dict(ds.attrs.get("bake", {}))
    check("ray_offset_world" in bake and "n_rays" in bake, f"{ds.path}: no bake settings (attrs['bake'])")
    exp = run.export_meta() if run.export_json.is_file() else None
    return CompareRun(run=run, dataset=ds, character=character, order=ds.order, bake=bake, model_meta=meta,
                      export_meta=exp, threads=threads)


def heldout_frames(ctx: CompareRun, max_frames: int | None = None) -> FrameSet:
    """The done held-out frames of the dataset (``max_frames``: evenly spaced subset), with their baked
    positions and frames (the arrays the bake traced) and baked visibility."""
    ds = ctx.dataset
    rows = ds.split_rows("heldout") if "heldout" in ds.splits else np.zeros(0, np.int64)
    if len(rows) == 0:
        raise PrtError(f"{ds.path}: no baked held-out frames to compare on (use --clip NAME)")
    if max_frames is not None:
        rows = rows[evenly_spaced(len(rows), max_frames)]
    d = ds.rows(rows, ("pose", "positions", "frames", "visibility"))
    names = ds.clip_names
    clips, frame_index = [names[i] for i in ds.clip_id[rows]], ds.frame_index[rows].astype(np.int64)
    fs = FrameSet(features=d["pose"].astype(np.float32), positions=d["positions"].astype(np.float32),
                  frames=d["frames"].astype(np.float32), clips=clips, frame_index=frame_index, rows=rows,
                  baked_visibility=d["visibility"].astype(np.float32))
    if not is_deformable(ds.attrs):  # a vertex cache has no skeleton to pose
        fs.local, fs.skin, fs.sources = row_poses(ctx, clips, frame_index)
    return fs


def row_poses(ctx: CompareRun, clips: list[str], frame_index: np.ndarray) -> tuple[np.ndarray, np.ndarray, list[str]]:
    """The poses of the dataset frames ``(clips[f], frame_index[f])``: :meth:`~prt_torch.bake.store.BakedDataset.
    frame_poses` (the one clip-name rule, posed as the bake posed them)."""
    return ctx.dataset.frame_poses(clips, frame_index, ctx.character)


def clip_frames(ctx: CompareRun, clip: str, max_frames: int | None = None) -> FrameSet:
    """A named clip posed with the bake's code (LBS, vertex frames from the dataset's cluster axes): a clip of the
    dataset's split (e.g. a held-out frame range of a training clip) or of the character, by the one rule
    (:meth:`~prt_torch.bake.store.BakedDataset.clip_by_name`) at the dataset's frame rate; ``max_frames``: evenly
    spaced subset."""
    from prt_torch.rig.vertex_frames import vertex_frames

    ch, ds = ctx.character, ctx.dataset
    if is_deformable(ds.attrs):
        return deformable_clip_frames(ctx, clip, max_frames)
    plan = ds.clip_by_name(clip, ch, recorded_fps(ds.attrs))
    poses = ch.pose(plan.clip)
    idx = evenly_spaced(poses.num_frames, max_frames if max_frames is not None else poses.num_frames)
    skin = poses.skin[idx]
    pos, nrm = ch.skin_mesh(skin)
    frames = vertex_frames(nrm, skin, ds.cluster, ds.cluster_axis, ds.cluster_bone)
    return FrameSet(features=np.asarray(poses.features[idx], dtype=np.float32), positions=pos.astype(np.float32),
                    frames=np.asarray(frames, dtype=np.float32), clips=[clip] * len(idx),
                    frame_index=plan.frame_index[idx], rows=np.full(len(idx), -1, np.int64),
                    local=poses.local[idx], skin=skin, sources=[plan.source] * len(idx))


def deformable_clip_frames(ctx: CompareRun, clip: str, max_frames: int | None = None) -> FrameSet:
    """A cached sequence of a deformable (cloth) run, positions and features from the source its config selects
    (:attr:`prt_torch.bake.deformable.DeformableSource.read`), frames by the bake's rule
    (:func:`~prt_torch.bake.deformable.posed_frames` with the dataset's clusters); ``max_frames``: evenly spaced
    subset."""
    from prt_torch.bake.deformable import frame_operator, posed_frames, source_of

    ds = ctx.dataset
    cfg = ds.run_config()  # validated (prt_torch.bake.store.recorded_run_config)
    check(cfg is not None, f"{ds.path}: records no run config (a deformable run's sequences need it)")
    cfg.run_dir = ctx.run.path
    source = source_of(cfg)
    check(source is not None, f"{ds.path}: its recorded config selects no deformable source")
    seq = source.read(cfg, clip)
    check(seq.positions.shape[1] == ctx.character.num_vertices,
          f"sequence {clip!r}: {seq.positions.shape[1]} vertices, the run's character {ctx.character.num_vertices}")
    idx = evenly_spaced(len(seq.positions), max_frames if max_frames is not None else len(seq.positions))
    pos = seq.positions[idx]
    _, frames = posed_frames(frame_operator(ctx.character, ds.cluster), pos)
    return FrameSet(features=seq.features[idx], positions=pos, frames=frames, clips=[clip] * len(idx),
                    frame_index=np.asarray(idx, np.int64), rows=np.full(len(idx), -1, np.int64))


def _time_methods(methods: dict[str, MethodBase], fs: FrameSet, req: RadianceRequest,
                  bar: Any) -> tuple[dict[str, np.ndarray], dict[str, dict[str, np.ndarray]], dict[str, list[float]]]:
    """Run every method on every frame, round-robin (the order rotates each frame), batch 1; returns visibility
    ``{name: (F, V, C)}``, radiance ``{name: {brdf: (F, V, 3)}}`` (radiance methods) and seconds per call."""
    f_n = fs.n_frames
    vis: dict[str, np.ndarray] = {}
    rad: dict[str, dict[str, np.ndarray]] = {}
    secs: dict[str, list[float]] = {n: [] for n in methods}
    names = list(methods)
    first = fs.batch(0)
    for m in methods.values():  # warm-up, untimed (first-call allocations, ORT arena)
        if m.output == "visibility":
            m.visibility(first)
        else:
            m.radiance(first, req)
    for f in range(f_n):
        b = fs.batch(f)
        for j in range(len(names)):
            n = names[(f + j) % len(names)]
            m = methods[n]
            t0 = time.perf_counter()
            out = m.visibility(b) if m.output == "visibility" else m.radiance(b, req)
            secs[n].append(time.perf_counter() - t0)
            if m.output == "visibility":
                if n not in vis:
                    vis[n] = np.empty((f_n,) + np.shape(out)[1:], np.float32)
                vis[n][f] = out[0]
            else:
                for brdf, r in out.items():
                    rad.setdefault(n, {}).setdefault(brdf, np.empty((f_n,) + np.shape(r)[1:], np.float32))[f] = r[0]
        bar.advance()
    return vis, rad, secs


def run_compare(run_dir: str | Path | RunDir, methods: list[str] | None = None, clip: str | None = None,
                max_frames: int | None = None, env: str | Path | None = None, dataset: str | Path | None = None,
                image_frames: int = 8, reference_frames: int = 4, reference_rays: int = 512, threads: int = 2,
                log: Callable[[str], None] | None = None, progress: bool = False, motion: str | Path | None = None,
                motion_fps: float | None = None, scene: Any = None, light: str = "sky", sun_size: float | None = None,
                sun_power: float | None = None) -> dict[str, Any]:
    """Compare methods on a run (see :mod:`prt_torch.compare`); writes the compare directory; returns the JSON.

    Args:
        run_dir: a trained run.
        methods: method names (default: every registered method the run can provide); ``sh_truth`` is added.
        clip: a named clip of the character to pose and trace (default: the dataset's held-out frames).
        max_frames: evenly spaced subset of at most this many frames.
        env: an HDR environment map (default: the player's procedural sky).
        dataset: the dataset (default: the run's, else the one in ``model.json``).
        image_frames: frames rendered for image PSNR (evenly spaced, the strip frame included).
        reference_frames: frames of the Monte-Carlo reference (the strip frame included; 0 disables).
        reference_rays: hemisphere rays per vertex of each of the two reference estimates.
        threads: onnxruntime threads of the learned methods.
        log: one-line progress notes; progress: rich progress bars.
        motion: a motion file retargeted onto the character (:mod:`prt_torch.rig.retarget`) and compared as the
            clip ``motion:<file stem>`` (``motion_fps``: its rate, default the dataset's).
        light: ``"sky"`` (the player's lighting: ``env`` or the procedural sky + sun), ``"smooth"`` (``env`` or the
            sky without its sun) or ``"sun"`` (that plus a sun disk of ``sun_size`` degrees and ``sun_power``):
            :func:`prt_torch.compare.reference.light_spec`; every method and the reference see the same light.
        scene: a :class:`~prt_torch.scene.config.SceneConfig` (default: the run's recorded scene); with a floor or
            a second character, ``compare.json`` gains ``ground`` and ``scene`` (:mod:`prt_torch.compare.ground`).
    """
    from prt_torch.eval.evaluate import ProgressBar
    from prt_torch.player.lighting import load_lighting
    from prt_torch.player.material import surface_albedo

    check(max_frames is None or max_frames >= 1, f"--frames must be >= 1, got {max_frames}")
    note = log or (lambda s: None)
    ctx = load_compare_run(run_dir, dataset, threads)
    if motion is not None:
        from prt_torch.rig.retarget import retarget_file

        fps = motion_fps or recorded_fps(ctx.dataset.attrs)
        mclip, report = retarget_file(motion, ctx.character, fps=fps)
        clip = f"motion:{mclip.name}"
        ctx.character.clips[clip] = mclip
        note(report.summary())
    names = resolve(methods, ctx)
    fs = clip_frames(ctx, clip, max_frames) if clip else heldout_frames(ctx, max_frames)
    from prt_torch.compare.reference import light_spec, sky_spec, spec_reference, spec_sh

    if light == "sky":
        spec = sky_spec(env)
        lighting = load_lighting(env, ctx.order)
    else:
        from prt_torch.player.lighting import lighting_from_sh

        spec = light_spec(light, env, *(() if sun_size is None else (sun_size,)), sun_power=sun_power)
        lighting = lighting_from_sh(spec_sh(spec, ctx.order), 3, source=spec.source)
    # the player's look: its BRDFs (the character's own material too) and its base colour, for every row and figure
    rpos, brdfs = player_brdfs(ctx.order, ctx.run, ctx.character)
    albedo = surface_albedo(ctx.character)
    sa = albedo.apply  # surface radiance (the identity for a white character)
    strip_b = strip_brdf(rpos)
    camera = player_camera(ctx.character, positions=fs.positions if is_deformable(ctx.dataset.attrs) else None)
    req = RadianceRequest(lighting, dict(rpos), brdfs, camera.eye, extra={"light_spec": spec})
    insts: dict[str, MethodBase] = {}
    for n in names:
        m = METHODS[n]()
        m.prepare(ctx, fs)
        insts[n] = m
    source = f"clip {clip!r} posed and ray-traced here" if clip else "done held-out frames of the dataset"
    note(f"{fs.n_frames} frames ({source}), {ctx.n_vertices} vertices; methods: {', '.join(names)}")
    bar = ProgressBar(progress, fs.n_frames, "methods, round-robin")
    try:
        vis, rad_direct, secs = _time_methods(insts, fs, req, bar)
    finally:
        bar.stop()
    truth = vis[TRUTH]
    shader = ShippingShader({"light": lighting}, rpos, camera.eye, paths=("lobes",))
    vis_methods = [n for n in names if insts[n].output == "visibility"]

    # -- pass 1: vertex radiance errors over every frame, and the per-frame shadow gap ----------------------------
    stats = {n: {b: RadianceStats() for b in rpos} for n in names}
    gap = np.zeros(fs.n_frames)
    for sl, res in shader.shade({n: vis[n] for n in vis_methods}, fs.frames, fs.positions):
        for b in rpos:
            d = res[("light", b, "lobes")]
            for n in names:
                pred = d[n] if n in d else rad_direct[n][b][sl]
                stats[n][b].add(sa(pred), sa(d[TRUTH]))
            if b == strip_b:
                gap[sl] = np.abs(sa(d[TRUTH]) - sa(d["unshadowed"])).mean(axis=(1, 2)) if "unshadowed" in d else 0.0
    strip_f = int(np.argmax(gap))
    img_idx = evenly_spaced(fs.n_frames, max(image_frames, 1), must=[strip_f])
    ref_idx = evenly_spaced(fs.n_frames, reference_frames, must=[strip_f]) if reference_frames > 0 else \
        np.zeros(0, np.int64)
    all_idx = np.union1d(img_idx, ref_idx)

    # -- pass 2: images (vs sh_truth on img_idx, vs the reference on ref_idx) -----------------------------------
    sub = {n: vis[n][all_idx] for n in vis_methods}
    shaded = shader.shade_all(sub, fs.frames[all_idx], fs.positions[all_idx])
    img = {n: {b: ImageStats() for b in rpos} for n in names}
    ref_img = {n: {b: ImageStats() for b in rpos} for n in [*names, "estimate_b"]}
    ref_rad = {n: {b: RadianceStats() for b in rpos} for n in [*names, "estimate_b"]}
    strip: dict[str, Any] = {}
    faces = np.asarray(ctx.character.faces)
    offset = float(ctx.bake["ray_offset_world"])
    light_ref = reference_light(env) if light == "sky" else spec_reference(spec)
    bar = ProgressBar(progress, len(all_idx), "images and reference")
    renderer = ImageRenderer(ctx.character.rest_vertices, faces, camera, albedo=albedo)
    try:
        for j, f in enumerate(all_idx):
            pos = fs.positions[f]
            mask = renderer.mask(pos)
            per = {b: {n: (shaded[("light", b, "lobes")][n][j] if n in vis_methods else rad_direct[n][b][f])
                       for n in names} for b in rpos}
            if f in img_idx:
                for b in rpos:
                    fi = renderer.frame_images(pos, per[b], TRUTH, mask=mask)
                    for n in names:
                        img[n][b].add(*fi.sse[n])
                    if f == strip_f and b == strip_b:
                        strip["images"] = fi
            if f in ref_idx:
                pair = reference_pair(pos, fs.frames[f], faces, camera.eye, light_ref, brdfs, reference_rays, offset)
                mean = pair.mean
                front = front_facing(pos, fs.frames[f], camera.eye)
                for b in rpos:
                    cand = {REFERENCE: mean[b], "estimate_a": pair.a[b], "estimate_b": pair.b[b], **per[b]}
                    fi = renderer.frame_images(pos, cand, REFERENCE, mask=mask)
                    ref_s = sa(mean[b])[front]
                    for n in names:
                        ref_img[n][b].add(*fi.sse[n])
                        ref_rad[n][b].add(sa(per[b][n])[front], ref_s)
                    # noise: estimate b vs estimate a (tone map from the mean)
                    ref_img["estimate_b"][b].add(*_sse_between(fi, "estimate_b", "estimate_a"))
                    ref_rad["estimate_b"][b].add(sa(pair.b[b])[front], sa(pair.a[b])[front])
                    if f == strip_f and b == strip_b:
                        strip["reference"] = fi.images[REFERENCE]
            bar.advance()
    finally:
        bar.stop()
        renderer.close()

    # -- the JSON --------------------------------------------------------------------------------------------------
    out_methods: dict[str, Any] = {}
    for n in names:
        m = insts[n]
        ms = float(np.median(secs[n]) * 1e3)
        entry: dict[str, Any] = {
            "vis_rel_err": M.vis_rel_err(vis[n], truth) if n in vis else None,
            **_radiance_keys(stats[n], {b: img[n][b].psnr for b in rpos}),
            "bytes": int(m.bytes()), "ms_per_frame": ms, "fps": 1e3 / ms if ms > 0 else float("inf"),
            "output": m.output, "runtime": m.runtime, **m.info()}
        if len(ref_idx):
            entry["vs_reference"] = {"vis_rel_err": None,
                                     **_radiance_keys(ref_rad[n], {b: ref_img[n][b].psnr for b in rpos}),
                                     "bytes": entry["bytes"], "ms_per_frame": ms, "fps": entry["fps"]}
        out_methods[n] = entry
    result: dict[str, Any] = {
        "frames": fs.n_frames, "clips": sorted(set(fs.clips)), "source": source,
        "n_vertices": ctx.n_vertices, "sh_order": ctx.order,
        "lighting": f"{lighting.source}: {len(lighting.dirs)} ZH lobes of the windowed order-{ctx.order} SH "
                    f"(the player's lighting, lobes path)",
        "lighting_path": "lobes", "light": light, "brdfs": list(rpos),
        "image_frames": int(len(img_idx)),
        "strip_frame": {"index": strip_f, "clip": fs.clips[strip_f], "frame_index": int(fs.frame_index[strip_f]),
                        "row": int(fs.rows[strip_f]), "brdf": strip_b},
        "material": _material_keys(ctx.character, albedo, strip_b),
        "timing": "median seconds per frame of each method's own run-time path (batch 1), all methods in one "
                  "process, round-robin per frame after one untimed warm-up call",
        "methods": out_methods,
    }
    if len(ref_idx):
        noise = _radiance_keys(ref_rad["estimate_b"], {b: ref_img["estimate_b"][b].psnr for b in rpos})
        result["reference"] = {
            "frames": int(len(ref_idx)), "frame_indices": [int(i) for i in ref_idx],
            "rays_per_estimate": int(reference_rays), "estimates": 2, "lighting": light_ref.source,
            "brdfs": {b: repr(brdfs[b]) for b in brdfs},
            "sampling": "randomised spherical-Fibonacci hemisphere about each normal, turned per vertex; "
                        "Embree visibility; analytic BRDF; mean of two independent estimates",
            "vertices": "vertex figures over the vertices facing the camera (n . (eye - p) > 0) only",
            "noise": noise,
            "note": "noise = estimate b vs estimate a; the mean of the two has about 6 dB less noise (PSNR ~6 dB "
                    "higher) than this pair, so vs_reference PSNRs near that ceiling are noise-limited",
        }
    from prt_torch.compare.ground import compare_scene

    catalogue = {b: r for b, r in rpos.items() if b in TAGS}  # the scene's figures: the catalogue BRDFs, as before
    result.update(compare_scene(ctx, fs, lighting, catalogue, scene=scene, image_frames=image_frames, threads=threads,
                                log=note))
    _write_outputs(ctx.run, result, strip, names)
    return result


def strip_brdf(rpos: dict[str, Any]) -> str:
    """The strip's BRDF: ``material`` when it is scored (a character with its own material: what the player
    plays by default, :func:`prt_torch.player.material.default_brdf`), else :data:`STRIP_BRDF`."""
    from prt_torch.rig.material import MATERIAL_BRDF

    return MATERIAL_BRDF if MATERIAL_BRDF in rpos else STRIP_BRDF


def _material_keys(character: Any, albedo: Any, strip_b: str) -> dict[str, Any]:
    """``compare.json``'s ``material``: the character's material and the base colour every figure and image used."""
    from prt_torch.rig.material import character_material

    return {**character_material(character).summary(), "albedo": albedo.summary(), "strip_brdf": strip_b,
            "rule": "the player's: radiance x base colour (per pixel in images for a textured character, per vertex "
                    "in vertex figures), for every method and the Monte-Carlo reference; one tone map per frame "
                    "fixed from the truth's surface radiance"}


def _sse_between(fi: Any, a: str, b: str) -> tuple[float, int]:
    from prt_torch.scoring.statistics import image_sse

    return image_sse(fi.images[a], fi.images[b], fi.mask)


def _radiance_keys(stats: dict[str, RadianceStats], psnr_img: dict[str, float | None]) -> dict[str, Any]:
    """``radiance_rel_rmse`` (pooled over the BRDFs) and the per-BRDF vertex/image figures."""
    sse = sum(s.sse for s in stats.values())
    sst = sum(s.sst for s in stats.values())
    out: dict[str, Any] = {"radiance_rel_rmse": float(np.sqrt(sse / max(sst, 1e-30)))}
    for b, s in stats.items():
        tag = TAGS.get(b, b)
        out[f"psnr_image_{tag}"] = psnr_img[b]
        out[f"radiance_rel_rmse_{tag}"] = s.rel_rmse
        out[f"psnr_vertex_{tag}"] = s.psnr
    return out


# -- outputs ---------------------------------------------------------------------------------------------------------

COLUMNS = ("vis_rel_err", "radiance_rel_rmse", "psnr_image_diffuse", "psnr_image_glossy", "bytes", "ms_per_frame",
           "fps")


def _fmt(x: Any, key: str = "") -> str:
    if x is None:
        return "-"
    if isinstance(x, float) and x == float("inf"):
        return "inf"
    if key == "bytes":
        return f"{int(x):,}"
    if key.startswith("psnr"):
        return f"{x:.2f}"
    if key in ("ms_per_frame", "fps"):
        return f"{x:.3g}"
    return f"{x:.4f}" if isinstance(x, float) else str(x)


def table_markdown(result: dict[str, Any]) -> str:
    """The Markdown table of ``compare.json``: one row per method, vs ``sh_truth`` then vs the reference (a
    character with its own material: its ``psnr_image_material`` column too, the BRDF the player plays)."""
    mat = ("psnr_image_material",) if "material" in result.get("brdfs", ()) else ()
    lines = [f"`prt compare`: {result['frames']} frames of {', '.join(result['clips'])} ({result['source']}), "
             f"{result['n_vertices']} vertices, order {result['sh_order']}; lighting: {result['lighting']}; "
             f"image PSNR on {result['image_frames']} frames (character pixels, the player's camera and tone map).",
             "", "| method | " + " | ".join(COLUMNS + mat) + " | run time |",
             "| --- | " + " | ".join("---:" for _ in COLUMNS + mat) + " | --- |"]
    for n, m in result["methods"].items():
        lines.append(f"| {n} | " + " | ".join(_fmt(m.get(c), c) for c in COLUMNS + mat) + f" | {m['runtime']} |")
    ref = result.get("reference")
    if ref:
        cols = ("radiance_rel_rmse", "psnr_image_diffuse", "psnr_image_glossy", *mat)
        lines += ["", f"Against the Monte-Carlo reference ({ref['frames']} frames, {ref['estimates']} x "
                  f"{ref['rays_per_estimate']} rays per vertex, analytic BRDFs, {ref['lighting']}):", "",
                  "| method | " + " | ".join(cols) + " |", "| --- | " + " | ".join("---:" for _ in cols) + " |"]
        for n, m in result["methods"].items():
            lines.append(f"| {n} | " + " | ".join(_fmt(m["vs_reference"].get(c), c) for c in cols) + " |")
        lines.append("| (reference noise: estimate b vs a) | " + " | ".join(_fmt(ref["noise"].get(c), c)
                                                                          for c in cols) + " |")
    from prt_torch.compare.ground import scene_markdown

    lines += scene_markdown(result)
    return "\n".join(lines) + "\n"


def _write_outputs(run: RunDir, result: dict[str, Any], strip: dict[str, Any], names: list[str]) -> None:
    run.compare_dir.mkdir(parents=True, exist_ok=True)
    atomic_write_json(run.compare_json, json.loads(json.dumps(result, default=float)))
    md = table_markdown(result)
    atomic_write_text(run.compare_table, md)
    figs = []
    if "images" in strip:
        fi = strip["images"]
        order = [TRUTH] + [n for n in names if n != TRUTH]
        imgs = [fi.images[n] for n in order]
        labels = ["sh_truth (ray-traced)"] + order[1:]
        diffs: list[np.ndarray | None] = [None] + [abs_diff_image(fi.images[n], fi.images[TRUTH]) for n in order[1:]]
        dlabels = [""] + [f"4x |{n} - sh_truth|" for n in order[1:]]
        if "reference" in strip:
            imgs.append(strip["reference"])
            labels.append("MC reference")
            diffs.append(abs_diff_image(strip["reference"], fi.images[TRUTH]))
            dlabels.append("4x |reference - sh_truth|")
        write_png(run.compare_strip, image_strip(imgs, labels, diffs, dlabels))
        s = result["strip_frame"]
        figs.append((run.compare_strip.name, f"frame {s['index']} ({s['clip']} #{s['frame_index']}): the largest "
                     f"truth vs unshadowed gap; {s['brdf']} x the base colour, one tone map from sh_truth; row 2: 4x "
                     f"|difference|"))
    plot_scatter(result, run.compare_scatter)
    figs.append((run.compare_scatter.name, "image PSNR (diffuse) vs milliseconds per frame"))
    if "ground" in result:
        figs.append((run.compare_ground.name, "the ground's cast shadow: whole-scene Embree truth | SHEXP | 4x diff"))
    body = html.escape(md)
    imgs_html = "".join(f"<h3>{html.escape(c)}</h3><img src='{html.escape(f)}' style='max-width:100%'>"
                        for f, c in figs)
    atomic_write_text(run.compare_html, "<!doctype html><html><head><meta charset='utf-8'><title>prt compare</title>"
                                        f"</head><body><pre>{body}</pre>{imgs_html}</body></html>\n")


def plot_scatter(result: dict[str, Any], path: Path) -> Path:
    """Image PSNR (diffuse) vs ms per frame, log x: filled = vs sh_truth (infinite values drawn at the top),
    hollow = vs the Monte-Carlo reference."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.4, 4.2))
    pts = [(n, m["ms_per_frame"], m.get("psnr_image_diffuse"), (m.get("vs_reference") or {}).get("psnr_image_diffuse"))
           for n, m in result["methods"].items()]
    finite = [p for _, _, p, _ in pts if p is not None and np.isfinite(p)]
    finite += [r for *_, r in pts if r is not None and np.isfinite(r)]
    top = (max(finite) if finite else 40.0) + 4.0
    for i, (n, ms, p, r) in enumerate(pts):
        c = f"C{i}"
        if p is not None:
            y = p if np.isfinite(p) else top
            ax.scatter([ms], [y], color=c, s=50, label=n, marker="^" if not np.isfinite(p) else "o")
            ax.annotate(n + (" (inf vs itself)" if not np.isfinite(p) else ""), (ms, y), textcoords="offset points",
                        xytext=(5, 4), fontsize=8)
        if r is not None:
            ax.scatter([ms], [r], facecolors="none", edgecolors=c, s=60)
    ax.set_xscale("log")
    ax.set(xlabel="milliseconds per frame (visibility, batch 1; log)", ylabel="image PSNR, diffuse (dB)",
           title="quality vs cost: filled = vs sh_truth, hollow = vs MC reference")
    ax.grid(True, which="both", alpha=0.3)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=110, bbox_inches="tight", format="png")
    plt.close(fig)
    return path

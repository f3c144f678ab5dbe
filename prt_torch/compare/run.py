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
from prt_torch.brdf.direct import peak_radiance, view_directions
from prt_torch.compare.methods import METHODS, CompareRun, FrameBatch, FrameSet, MethodBase, RadianceRequest, resolve
from prt_torch.compare.reference import compare_lights, front_facing, reference_pair, silhouette_mask
from prt_torch.errors import PrtError, check
from prt_torch.io import atomic_path, atomic_write_json, atomic_write_text
from prt_torch.rundir import RunDir
from prt_torch.scoring.images import ImageRenderer, clip_cameras, player_camera
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
#: a row with a peak term: ``<method>+peaks_<kind>`` (:func:`peaks_row`)
PEAKS_SEP = "+peaks_"
#: the truth of every ``+peaks`` row (always a row when there are peaks): ray-traced SH visibility for the residual,
#: exact (Embree) disc visibility for the peaks; the ceiling
PEAKS_TRUTH = f"{TRUTH}{PEAKS_SEP}exact"
#: default peak kinds of every visibility method (those the run has), plus ``exact`` for ``sh_truth``
DEFAULT_PEAK_KINDS = ("spheres", "learned")


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


#: the unshadowed visibility's key in the first shading pass when "unshadowed" is not a compared method (the strip
#: frame's rule)
GAP_UNSHADOWED = "\0unshadowed"


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


def peaks_row(method: str, kind: str) -> str:
    """The row name of ``method`` with the peak term of ``kind``: ``<method>+peaks_<kind>``."""
    return f"{method}{PEAKS_SEP}{kind}"


class _PeakKind(MethodBase):
    """A peak visibility kind (:class:`prt_torch.player.peaks.PeakVisibility`) timed round-robin like a method:
    ``visibility(batch) -> (B, V, P)`` the peaks' visible fractions (normals: the frames' third rows; skin: the frame
    set's)."""

    def __init__(self, pv: Any, fs: FrameSet, directions: np.ndarray, radii: np.ndarray, runtime: str) -> None:
        self.pv, self.fs, self.directions, self.radii, self.runtime = pv, fs, directions, radii, runtime

    def visibility(self, batch: FrameBatch) -> np.ndarray:
        skin = self.fs.skin[batch.index] if self.fs.skin is not None else None
        return self.pv(batch.positions, batch.frames[:, :, 2, :], skin, self.directions, self.radii)

    def bytes(self) -> int:
        return int(self.pv.bytes())


def _peak_kinds(ctx: CompareRun, fs: FrameSet, lights: Any, vis_methods: list[str], kinds: list[str] | None,
                ) -> tuple[dict[str, tuple[str, str]], dict[str, _PeakKind]]:
    """The ``+peaks`` rows ``{row: (base method, kind)}`` (:data:`PEAKS_TRUTH` first) and the peak kinds to time
    ``{kind: _PeakKind}``; none without peaks. ``kinds=None``: :data:`DEFAULT_PEAK_KINDS` the run has for every
    visibility method (+ ``exact`` for ``sh_truth``); a list: each kind for every visibility method (one the run
    cannot provide is a one-line error)."""
    from prt_torch.bake.peaks import DEFAULT_DISC_SIDE
    from prt_torch.player.peaks import PEAK_KINDS, learned_blockers_path, peak_visibility

    if not lights.peaks:
        return {}, {}
    run = ctx.run
    have = {"exact": True, "spheres": run.blockers_path.is_file() and fs.skin is not None,
            "learned": learned_blockers_path(run) is not None and fs.skin is not None}
    for k in kinds or ():
        check(k in PEAK_KINDS, f"--peak-kinds: unknown peak kind {k!r}: expected one of {', '.join(PEAK_KINDS)}")
        if not have[k]:
            why = "a skinned character" if fs.skin is None else \
                ("blocker spheres (prt export)" if k == "spheres" else "learned peak blockers (bake.peaks + train)")
            raise PrtError(f"--peak-kinds {k}: {run.path} has no {why}")
    rows: dict[str, tuple[str, str]] = {PEAKS_TRUTH: (TRUTH, "exact")}
    for n in vis_methods:
        ks = list(kinds) if kinds is not None else [k for k in DEFAULT_PEAK_KINDS if have[k]]
        for k in sorted(ks, key=PEAK_KINDS.index):
            rows.setdefault(peaks_row(n, k), (n, k))
    dirs = np.array([p.direction for p in lights.peaks], dtype=np.float64).reshape(-1, 3)
    radii = np.array([p.angular_radius for p in lights.peaks], dtype=np.float64)
    offset = float(ctx.bake["ray_offset_world"])
    timed: dict[str, _PeakKind] = {}
    for k in sorted({k for _, k in rows.values()}, key=PEAK_KINDS.index):
        pv = peak_visibility(k, run, ctx.character, offset=offset)
        blockers = getattr(pv, "blockers", None)  # spheres or learned capsules (exact: none)
        n_sph = 0 if blockers is None else len(blockers.radius)
        shape = "capsule" if getattr(pv, "capsules", None) is not None else "sphere"
        what = {"exact": f"Embree ({DEFAULT_DISC_SIDE}x{DEFAULT_DISC_SIDE} disc rays per vertex and peak)",
                "spheres": f"numba (cone-sphere kernel, {n_sph} blocker spheres)",
                "learned": f"numba (cone-{shape} kernel, {n_sph} learned peak {shape}s)"}[k]
        timed[k] = _PeakKind(pv, fs, dirs, radii, what)
    return rows, timed


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
                sun_power: float | None = None, peaks: int | str = "auto", peak_kinds: list[str] | None = None,
                residual_window: bool | None = None, silhouette: bool = True) -> dict[str, Any]:
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
        peaks: ``"auto"``, ``0`` or ``K``: the light split (:func:`prt_torch.compare.reference.compare_lights`); with
            peaks, every visibility method gains ``<method>+peaks_<kind>`` rows (:mod:`prt_torch.compare`).
        peak_kinds: the peak visibilities of the ``+peaks`` rows, each for every visibility method (default
            :data:`DEFAULT_PEAK_KINDS` the run has, + ``exact`` for ``sh_truth``; ``sh_truth+peaks_exact`` is always
            a row when there are peaks: the ``+peaks`` rows' truth).
        residual_window: the sinc window on the ``+peaks`` rows' residual lighting (default the player's,
            :data:`prt_torch.player.peaks.RESIDUAL_WINDOW`).
        silhouette: the silhouette rule (every row 0 at vertices facing away from the camera; ``False``: off, to
            measure what it changes).
    """
    from prt_torch.eval.evaluate import ProgressBar
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
    lights = compare_lights(light, env, ctx.order, peaks=peaks, sun_size=sun_size, sun_power=sun_power,
                            residual_window=residual_window)
    spec, lighting = lights.spec, lights.lighting
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
    vis_methods = [n for n in names if insts[n].output == "visibility"]
    prow, kinds = _peak_kinds(ctx, fs, lights, vis_methods, peak_kinds)
    rows = [*names, *prow]
    source = f"clip {clip!r} posed and ray-traced here" if clip else "done held-out frames of the dataset"
    note(f"{fs.n_frames} frames ({source}), {ctx.n_vertices} vertices; methods: {', '.join(names)}"
         + (f"; {len(lights.peaks)} peak light(s), peak kinds {', '.join(kinds)}" if kinds else "; no peak light"))
    bar = ProgressBar(progress, fs.n_frames, "methods, round-robin")
    try:
        vis, rad_direct, secs = _time_methods({**insts, **{PEAKS_SEP + k: pk for k, pk in kinds.items()}}, fs, req,
                                              bar)
    finally:
        bar.stop()
    pvis = {k: vis.pop(PEAKS_SEP + k) for k in kinds}  # (F, V, P) visible fractions of the peaks
    truth = vis[TRUTH]
    p_dirs = np.array([p.direction for p in lights.peaks], dtype=np.float64).reshape(-1, 3)
    p_powers = np.array([p.power for p in lights.peaks], dtype=np.float64).reshape(-1, 3)
    shade_lights = {"light": lighting, **({"residual": lights.residual} if prow else {})}
    shader = ShippingShader(shade_lights, rpos, camera.eye, paths=("lobes",))

    def row_radiance(res: dict[Any, dict[str, np.ndarray]], frames_idx: np.ndarray | slice) -> dict[str, dict[str,
                                                                                                          Any]]:
        """``{brdf: {row: (f, V, 3)}}`` of every row on the frames ``frames_idx`` of ``fs`` (``res``: the shader's
        output on them): methods on the whole lighting, ``+peaks`` rows the residual + the peak term; the
        silhouette rule applied (:func:`prt_torch.compare.reference.silhouette_mask`)."""
        fr, pos = fs.frames[frames_idx], fs.positions[frames_idx]
        front = silhouette_mask(pos, fr, camera.eye)[..., None] if silhouette else None
        view = view_directions(pos, camera.eye) if prow else None
        out: dict[str, dict[str, Any]] = {}
        for b in rpos:
            d = res[("light", b, "lobes")]
            per = {n: (d[n] if n in d else rad_direct[n][b][frames_idx]) for n in names}
            if prow:
                r = res[("residual", b, "lobes")]
                term = {k: peak_radiance(fr, view, p_dirs, p_powers, pv[frames_idx], brdfs[b])
                        for k, pv in pvis.items()}
                per.update({row: r[base] + term[k] for row, (base, k) in prow.items()})
            out[b] = {n: (a * front if front is not None else a) for n, a in per.items()}
        return out

    def truth_of(row: str) -> str:
        return PEAKS_TRUTH if row in prow else TRUTH

    # -- pass 1: vertex radiance errors over every frame, and the per-frame shadow gap ----------------------------
    stats = {n: {b: RadianceStats() for b in rpos} for n in rows}
    gap = np.zeros(fs.n_frames)
    # the strip frame (and with it the image and reference frames) is the frame of the largest shadow: sh_truth vs
    # the unshadowed visibility, shaded here whether or not "unshadowed" is a compared method, so that the scored
    # frames never depend on the method list
    shade_vis = {n: vis[n] for n in vis_methods}
    if "unshadowed" not in shade_vis:
        from prt_torch.scoring.lighting import unshadowed_visibility

        shade_vis[GAP_UNSHADOWED] = np.broadcast_to(unshadowed_visibility(ctx.order, ctx.bake), truth.shape)
    gap_key = "unshadowed" if "unshadowed" in vis_methods else GAP_UNSHADOWED
    for sl, res in shader.shade(shade_vis, fs.frames, fs.positions):
        per_b = row_radiance(res, sl)
        for b, per in per_b.items():
            for n in rows:
                stats[n][b].add(sa(per[n]), sa(per[truth_of(n)]))
            if b == strip_b:
                un = res[("light", b, "lobes")][gap_key]
                if silhouette:
                    un = un * silhouette_mask(fs.positions[sl], fs.frames[sl], camera.eye)[..., None]
                gap[sl] = np.abs(sa(per[TRUTH]) - sa(un)).mean(axis=(1, 2))
    strip_f = int(np.argmax(gap))
    img_idx = evenly_spaced(fs.n_frames, max(image_frames, 1), must=[strip_f])
    ref_idx = evenly_spaced(fs.n_frames, reference_frames, must=[strip_f]) if reference_frames > 0 else \
        np.zeros(0, np.int64)
    all_idx = np.union1d(img_idx, ref_idx)

    # -- pass 2: images (vs sh_truth on img_idx, vs the reference on ref_idx) -----------------------------------
    sub = {n: vis[n][all_idx] for n in vis_methods}
    shaded = row_radiance(shader.shade_all(sub, fs.frames[all_idx], fs.positions[all_idx]), all_idx)
    img = {n: {b: ImageStats() for b in rpos} for n in rows}
    ref_img = {n: {b: ImageStats() for b in rpos} for n in [*rows, "estimate_b"]}
    ref_rad = {n: {b: RadianceStats() for b in rpos} for n in [*rows, "estimate_b"]}
    strip: dict[str, Any] = {}
    strip_rows = _strip_rows(ctx, prow)
    faces = np.asarray(ctx.character.faces)
    offset = float(ctx.bake["ray_offset_world"])
    light_ref = lights.reference
    bar = ProgressBar(progress, len(all_idx), "images and reference")
    renderer = ImageRenderer(ctx.character.rest_vertices, faces, camera, albedo=albedo)
    # each image framed as the player frames that frame of its clip (the follow camera, the image-PSNR camera
    # contract: prt_torch.scoring.images.clip_cameras); a cloth sequence keeps its sequence camera
    cams = None if is_deformable(ctx.dataset.attrs) else clip_cameras(
        ctx.character, {n: ctx.dataset.clip_by_name(n, ctx.character, recorded_fps(ctx.dataset.attrs))
                        for n in dict.fromkeys(fs.clips[f] for f in all_idx)},
        [fs.clips[f] for f in all_idx], fs.frame_index[all_idx])
    try:
        for j, f in enumerate(all_idx):
            pos = fs.positions[f]
            if cams is not None:
                renderer.set_camera(cams[j])
            mask = renderer.mask(pos)
            per = {b: {n: shaded[b][n][j] for n in rows} for b in rpos}
            if f in img_idx:
                for b in rpos:
                    # one tone map per truth: sh_truth's for the methods, sh_truth+peaks_exact's for the +peaks rows
                    for t, group in ((TRUTH, names), (PEAKS_TRUTH, list(prow))):
                        if not group:
                            continue
                        fi = renderer.frame_images(pos, {n: per[b][n] for n in group}, t, mask=mask)
                        for n in group:
                            img[n][b].add(*fi.sse[n])
                        if f == strip_f and b == strip_b and t == TRUTH:
                            strip["images"] = fi
                    if f == strip_f and b == strip_b and strip_rows:  # the strip's +peaks rows: sh_truth's tone map
                        extra = renderer.frame_images(pos, {n: per[b][n] for n in [TRUTH, *strip_rows]}, TRUTH,
                                                      mask=mask)
                        strip["images"].images.update({n: extra.images[n] for n in strip_rows})
            if f in ref_idx:
                pair = reference_pair(pos, fs.frames[f], faces, camera.eye, light_ref, brdfs, reference_rays, offset)
                mean = pair.mean
                front = front_facing(pos, fs.frames[f], camera.eye)
                for b in rpos:
                    cand = {REFERENCE: mean[b], "estimate_a": pair.a[b], "estimate_b": pair.b[b], **per[b]}
                    fi = renderer.frame_images(pos, cand, REFERENCE, mask=mask)
                    ref_s = sa(mean[b])[front]
                    for n in rows:
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
    ms_of = {n: float(np.median(secs[n]) * 1e3) for n in secs}
    for n in rows:
        base, kind = prow.get(n, (n, ""))
        m = insts[base]
        pk = kinds.get(kind)
        ms = ms_of[base] + (ms_of[PEAKS_SEP + kind] if pk is not None else 0.0)
        nbytes = int(m.bytes()) + (pk.bytes() if pk is not None else 0)
        entry: dict[str, Any] = {
            "vis_rel_err": M.vis_rel_err(vis[base], truth) if base in vis else None,
            **_radiance_keys(stats[n], {b: img[n][b].psnr for b in rpos}),
            "bytes": nbytes, "ms_per_frame": ms, "fps": 1e3 / ms if ms > 0 else float("inf"),
            "output": m.output, "runtime": m.runtime + (f" + {pk.runtime}" if pk is not None else ""),
            **(m.info() if pk is None else {"base_method": base, "peak_kind": kind, "truth": PEAKS_TRUTH,
                                             "peak_ms_per_frame": ms_of[PEAKS_SEP + kind],
                                             "peak_bytes": pk.bytes()})}
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
        "peaks": [p.to_dict() for p in lights.peaks],
        "peak_kinds": list(kinds),
        "residual_lighting": None if lights.residual is None else
        f"{lights.residual.source}: {len(lights.residual.dirs)} ZH lobes of the order-{ctx.order} SH, "
        f"{'windowed' if lights.residual_window else 'no window'} (the +peaks rows)",
        "silhouette": SILHOUETTE_RULE if silhouette else "none: RPO radiance as shaded at every vertex",
        "image_frames": int(len(img_idx)),
        "strip_frame": {"index": strip_f, "clip": fs.clips[strip_f], "frame_index": int(fs.frame_index[strip_f]),
                        "row": int(fs.rows[strip_f]), "brdf": strip_b},
        "material": _material_keys(ctx.character, albedo, strip_b),
        "timing": "median seconds per frame of each method's own run-time path (batch 1), all methods in one "
                  "process, round-robin per frame after one untimed warm-up call; a +peaks row: its method's plus "
                  "its peak kind's (timed in the same round-robin)",
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
            "vertices": "vertex figures over the vertices facing the camera (n . (eye - p) > 0) only; "
                        + ("the silhouette rule: " + SILHOUETTE_RULE if silhouette else "no silhouette rule"),
            "noise": noise,
            "note": "noise = estimate b vs estimate a; the mean of the two has about 6 dB less noise (PSNR ~6 dB "
                    "higher) than this pair, so vs_reference PSNRs near that ceiling are noise-limited",
        }
    from prt_torch.compare.ground import compare_scene

    catalogue = {b: r for b, r in rpos.items() if b in TAGS}  # the scene's figures: the catalogue BRDFs, as before
    result.update(compare_scene(ctx, fs, lighting, catalogue, scene=scene, image_frames=image_frames, threads=threads,
                                log=note, lights=lights, reference_frames=reference_frames,
                                reference_rays=reference_rays))
    _write_outputs(ctx.run, result, strip, [*names, *strip_rows])
    return result


#: compare.json ``silhouette``: the one rule at silhouette vertices (:func:`~.reference.silhouette_mask`)
SILHOUETTE_RULE = ("every row and the reference have radiance 0 at vertices whose normal faces away from the camera "
                   "(n . (eye - p) <= 0), as the analytic BRDFs of the reference do")


def _strip_rows(ctx: CompareRun, prow: dict[str, tuple[str, str]]) -> list[str]:
    """The ``+peaks`` rows of the strip (readable: the methods' rows, then these two): the shipped learned kind with
    its best peak kind (``learned``, else ``spheres``), and the ceiling :data:`PEAKS_TRUTH`."""
    kind = ctx.model_meta.get("default_kind", "mlp")
    cands = [peaks_row(f"learned_{kind}", k) for k in ("learned", "spheres")]
    return [r for r in [next((c for c in cands if c in prow), None), PEAKS_TRUTH] if r is not None and r in prow]


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
             *_peaks_lines(result),
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


def _peaks_lines(result: dict[str, Any]) -> list[str]:
    """The table's note on the light split: the peaks, the residual lighting, the +peaks rows' truth."""
    peaks = result.get("peaks") or []
    if not peaks:
        return []
    desc = "; ".join(f"direction {np.round(p['direction'], 3).tolist()}, half-angle {p['angular_radius_deg']:.3g} "
                     f"deg, radiance {np.round(p['radiance'], 1).tolist()}" for p in peaks)
    return ["", f"Peak lights ({len(peaks)}): {desc}. `<method>+peaks_<kind>` rows: the method's visibility under the "
            f"residual ({result.get('residual_lighting')}) + each peak shaded with the analytic BRDF and the `<kind>` "
            f"peak visibility; their figures vs sh_truth are against `{PEAKS_TRUTH}`."]


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

"""``prt demo``: the whole job on the built-in character, end to end, into ``runs/demo/``.

Steps (each reused when already done for the same inputs): bake the training and held-out clips
(resumable), fit the models, export to ONNX, play the held-out clip into an MP4 with onnxruntime,
and write a side-by-side PNG (Monte-Carlo reference | ray-traced truth | model | unshadowed) and the metrics.

With peak lights (the player's default: the sky's sun split off, ``bake.peaks`` / ``train.peaks`` in the config
for its learned shadows) every column but the reference is the residual through SH plus the peaks' term: the truth
with exact (Embree) peak visibility, the model with the player's (the learned peak blockers), the unshadowed column
with none. The reference is the rendering integral itself (:mod:`prt_torch.compare.reference`: Embree rays, the
analytic BRDF, the residual sky at full resolution and the sun as a disk), one frame, :data:`REFERENCE_RAYS` rays.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path
from typing import Any

import numpy as np

HELP = ("Run a config's whole pipeline (bake, fit, export, the held-out comparison and video) into runs/<name>/; "
        "default: configs/demo.yaml, the built-in character, into runs/demo/.")

#: hemisphere rays per vertex of each of the comparison's two Monte-Carlo reference estimates (one frame)
REFERENCE_RAYS = 64
#: the truth column's exact peak visibility: ``side x side`` rays per vertex to each disc (every held-out frame)
TRUTH_DISC_SIDE = 4


def default_config() -> Path:
    """``configs/demo.yaml`` next to the package (a source checkout)."""
    return Path(__file__).resolve().parents[2] / "configs" / "demo.yaml"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--config", default=None, help="run config (default: configs/demo.yaml)")
    parser.add_argument("--run-dir", default=None, help="output directory (default: runs/<name> of the config)")
    parser.add_argument("--env", default=None, help="HDR environment map for the video and PNG (default: procedural "
                                                    "sun and sky)")
    parser.add_argument("--brdf", default="phong", help="BRDF of the video and PNG (default: phong)")
    parser.add_argument("--max-frames", "--frames", dest="max_frames", type=int, default=None,
                        help="play at most this many held-out frames")
    parser.add_argument("--size", default="640x400", help="image size HxW (default 640x400; each side 1..8192)")
    parser.add_argument("--force", action="store_true", help="redo fit and export even if up to date")


def run(args: argparse.Namespace) -> int:
    from prt_torch import limits
    from prt_torch.bake.runner import bake
    from prt_torch.brdf.rpo import CATALOGUE
    from prt_torch.commands import _validate as V
    from prt_torch.config import load_config
    from prt_torch.errors import PrtError
    from prt_torch.export.run import DEFAULT_BRDFS, export_run
    from prt_torch.fit.train import train_dataset, train_key
    from prt_torch.io import atomic_write_json
    from prt_torch.progress import make_console
    from prt_torch.rundir import RunDir

    # every argument is checked before anything is baked or written
    h, w = limits.parse_size(args.size)
    if args.max_frames is not None:
        limits.check_int(args.max_frames, "--max-frames", 1, limits.MAX_FRAMES)
    if args.brdf.lower().endswith(".npz"):
        V.input_file(args.brdf, "--brdf")
    else:
        V.names(args.brdf, "--brdf", tuple(b for b in DEFAULT_BRDFS if b in CATALOGUE))
    if args.env is not None:
        V.input_file(args.env, "--env")
    if args.run_dir is not None:
        V.run_dir(args.run_dir, "--run-dir")
    console = make_console(stderr=True)
    t_all = time.perf_counter()
    cfg_path = Path(args.config) if args.config else default_config()
    cfg = load_config(cfg_path, run_dir=args.run_dir or None)
    if not cfg.character.heldout_clips:
        raise PrtError(f"{cfg_path}: the demo needs a held-out clip (character.heldout_clips)")
    run = RunDir(cfg.out_dir)
    run.path.mkdir(parents=True, exist_ok=True)
    seconds: dict[str, float] = {}

    console.rule(f"[bold]prt demo -> {run.path}")
    t0 = time.perf_counter()
    console.print("[bold]1/5 bake[/] (Embree ground truth; resumes finished blocks)")
    bake(cfg)
    ds = run.dataset()
    seconds["bake"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    if not args.force and _trained(run, train_key(ds, cfg.train)):
        console.print("[bold]2/5 fit[/]: up to date, reusing the trained models")
    else:
        console.print("[bold]2/5 fit[/] (PCA + ridge / per-cluster MLP, L-BFGS)")
        with console.status("fitting ..."):
            train_dataset(ds, run, cfg.train)
    seconds["fit"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    console.print("[bold]3/5 export[/] (ONNX graphs, parity with torch on held-out poses)")
    meta = export_run(run, force=args.force, console=console)
    seconds["export"] = time.perf_counter() - t0

    heldout = list(cfg.character.heldout_clips)
    if not heldout:
        raise PrtError(f"{cfg_path}: the demo needs a held-out clip (character.heldout_clips)")
    from prt_torch.player import Player
    from prt_torch.rig.config import as_clip_range

    entry = as_clip_range(heldout[0])  # a whole clip or a frame range of one (a within-clip split)
    clip = entry.dataset_name

    t0 = time.perf_counter()
    scene = cfg.scene if cfg.scene is not None and (cfg.scene.ground is not None or len(cfg.scene.characters) > 1) \
        else None
    if scene is not None:
        from prt_torch.scene.config import write_run_scene

        write_run_scene(run, scene)  # `prt play --ground` and `prt compare` read the run's scene
    elif run.scene_json.is_file():
        run.scene_json.unlink()
    player = Player(run, env=args.env, brdf=args.brdf, window_size=(h, w))
    held = ds.clip_by_name(clip, player.character, cfg.character.fps)  # its frames, by the one clip-name rule
    scene_metrics: dict[str, Any] | None = None
    try:
        console.print(f"[bold]4/5 compare[/] held-out '{clip}': reference | truth | model | unshadowed -> "
                      f"{run.demo_image}")
        comp = compare_heldout(player, ds, clip, run.demo_image, env=args.env, locals_=held.clip.local)
        if scene is not None:
            console.print("  the scene (floor, cast shadows): whole-scene Embree truth vs the player's composition")
            scene_metrics = scene_row(run, ds, scene, held.source, comp["comparison_row"], cfg.character.fps,
                                      args.env, args.brdf, (h, w), run.demo_image)
        seconds["compare"] = time.perf_counter() - t0
        t0 = time.perf_counter()
        console.print(f"[bold]5/5 play[/] held-out clip '{clip}' with onnxruntime -> {run.demo_video}"
                      + (" (the scene: floor and cast shadows)" if scene is not None else ""))
        if scene is None:
            res = player.play(held.clip, out=run.demo_video, max_frames=args.max_frames,
                              timings=run.timings_path(run.demo_video))
            play_summary = {"frames": res.frames, **res.summary}
        else:
            play_summary = play_scene(run, scene, held.clip, args, (h, w))
        seconds["play"] = time.perf_counter() - t0
    finally:
        player.close()
    fit_metrics = run.read_json(run.metrics_json) if run.metrics_json.is_file() else {}
    seconds["total"] = time.perf_counter() - t_all
    metrics = {
        "heldout_clip": clip, "n_vertices": meta["n_vertices"], "sh_order": meta["sh_order"],
        "model_kind": meta["model_kind"], "brdf": player.rpo.name, "lighting": player.lighting.source,
        "zh_fit_rel_error": player.lighting.rel_error,
        "onnx_parity_rel_error": {k: v["rel_error"] for k, v in meta["parity"].items()},
        "heldout": comp, "fit": fit_metrics,
        "play": {"frames": play_summary["frames"], "compute_fps": play_summary.get("compute_fps"),
                 "total_fps": play_summary.get("total_fps")},
        "seconds": seconds,
    }
    if scene_metrics is not None:
        metrics["scene"] = scene_metrics
    atomic_write_json(run.demo_metrics, metrics)
    if "reference" in comp:
        r = comp["reference"]
        console.print(f"frame {r['row']} vs the Monte-Carlo reference: radiance rel. RMSE truth "
                      f"{r['radiance_rel_rmse_truth']:.4f}, model {r['radiance_rel_rmse_model']:.4f}, unshadowed "
                      f"{r['radiance_rel_rmse_unshadowed']:.4f}")
    console.print(f"held-out '{clip}': visibility rel. error model {comp['vis_rel_err_model']:.4f} vs "
                  f"unshadowed {comp['vis_rel_err_unshadowed']:.4f}; radiance rel. RMSE model "
                  f"{comp['radiance_rel_rmse_model']:.4f} vs unshadowed {comp['radiance_rel_rmse_unshadowed']:.4f}")
    if scene_metrics is not None:
        console.print(f"scene (floor + character) vs whole-scene truth: image PSNR "
                      f"{scene_metrics['scene_psnr_image']:.1f} dB; "
                      f"character in scene: visibility rel. error {scene_metrics['vis_rel_err_in_scene']:.4f} "
                      f"(self-only {scene_metrics['vis_rel_err_self_only']:.4f})")
    console.print(f"playback: {play_summary.get('compute_fps', 0):.0f} frames/s compute path, "
                  f"{play_summary.get('total_fps', 0):.1f} frames/s with rendering + encoding")
    console.print(f"wrote {run.demo_video}, {run.demo_image}, {run.demo_metrics} in {seconds['total']:.0f} s")
    return 0


def _trained(run: Any, key: str) -> bool:
    """Whether the run's models are up to date for ``key`` AND verify against their commit record (a run
    trained by an older version, or damaged since, is trained again instead of failing later)."""
    from prt_torch.errors import ArtifactError

    if not run.is_current("train", key, (run.model_path(), run.model_json)):
        return False
    try:
        run.model_meta()
    except ArtifactError:
        return False
    return True


def compare_heldout(player: Any, ds: Any, clip: str, out: Path, env: Any = None, locals_: Any = None,
                    reference_rays: int = REFERENCE_RAYS) -> dict[str, Any]:
    """Reference vs truth vs model vs unshadowed on every baked frame of ``clip`` (ORT path), and the PNG ``out``.

    ``ds``: the run's :class:`prt_torch.bake.store.BakedDataset`; ``locals_``: the clip's ``(F, J, 4, 4)`` local
    joint transforms (the skinning matrices that carry the peak blockers; ``None`` only for a run without them).
    Returns metrics: visibility relative L2 errors (model and the unshadowed hemisphere vs the ray-traced truth),
    radiance relative RMSEs under the player's lighting and BRDF (peaks included), and for the frame shown the
    figures against the Monte-Carlo reference (``reference``; front-facing vertices).
    """
    from prt_torch.errors import PrtError
    from prt_torch.player.posing import PoseBatch
    from prt_torch.player.video import write_png

    rows = ds.clip_rows(clip)
    if rows.size == 0:
        raise PrtError(f"no baked frames of {clip!r} in {ds.path}")
    data = {k: np.asarray(v, dtype=np.float32)
            for k, v in ds.rows(rows, ("visibility", "pose", "positions", "frames")).items()}
    truth, pose, pos, frames = data["visibility"], data["pose"], data["positions"], data["frames"]
    n, v = pos.shape[:2]
    eye = player.eye
    view = eye[None, None, :] - pos
    view /= np.linalg.norm(view, axis=-1, keepdims=True)
    skin = None
    if locals_ is not None:  # the baked frames' skinning matrices (what poses the peak blockers), by the one
        skin = ds.row_poses(rows, player.character)[1]  # clip-name rule (a held-out range of a training clip too)
    state = PoseBatch(np.ascontiguousarray(pos.transpose(0, 2, 1)),
                      np.ascontiguousarray(frames[:, :, 2].transpose(0, 2, 1)),
                      np.ascontiguousarray(frames.reshape(n, v, 9).transpose(0, 2, 1)),
                      np.ascontiguousarray(view.transpose(0, 2, 1), dtype=np.float32), pose, skin=skin)
    model = player.visibility(pose)
    hemi = np.broadcast_to(player.unshadowed, truth.shape)
    peak_vis = _peak_visibilities(player, ds, state)
    rad = {name: player.shade(state, visibility=vis) + _peak_term(player, state, peak_vis.get(name))
           for name, vis in (("truth", truth), ("model", model), ("unshadowed", hemi))}

    def rel(a: np.ndarray, b: np.ndarray) -> float:
        return float(np.linalg.norm(a - b) / max(np.linalg.norm(b), 1e-12))

    # the frame with the most self-shadowing (largest truth vs unshadowed radiance gap)
    gap = np.abs(rad["truth"] - rad["unshadowed"]).mean(axis=(1, 2))
    i = int(np.argmax(gap))
    ref = _reference(player, ds, state, i, env, reference_rays)
    player.exposure = None
    player.colors(rad["unshadowed"][i])  # one exposure for all four panels, from the unshadowed one
    panels, images = [], {}
    labels = {"reference": "reference (Monte-Carlo)", "truth": "ray-traced truth",
              "model": f"model ({player.bundle.meta['model_kind']})", "unshadowed": "unshadowed"}
    for name in ("reference", "truth", "model", "unshadowed"):
        r = np.broadcast_to(ref, (n, *ref.shape)) if name == "reference" else rad[name]
        images[name] = player.render_frame(state, r, index=i)
        panels.append(_label(images[name], labels[name]))
    # second row: the fraction of light blocked at each vertex, 1 - lit / unshadowed (white = fully shadowed),
    # for the truth and the model, and their absolute difference, so self-shadowing is plain to see; under the
    # reference the model's image against it
    from prt_torch.player.tonemap import ToneMap
    from prt_torch.scoring.strips import abs_diff_image

    unlit = rad["unshadowed"][i].sum(-1)
    blocked = {name: np.clip(1.0 - rad[name][i].sum(-1) / np.maximum(unlit, 1e-12), 0.0, 1.0)
               for name in ("truth", "model")}
    blocked["error"] = np.abs(blocked["model"] - blocked["truth"])
    player.exposure = ToneMap(1.0, None)  # type: ignore[arg-type]  # plain clip to [0, 1], then gamma
    row2 = [_label(abs_diff_image(images["model"], images["reference"]), "4x |model - reference|")]
    for name, label in (("truth", "light blocked: truth"), ("model", "light blocked: model"),
                        ("error", "|model - truth|")):
        grey = np.repeat(blocked[name][None, :, None], 3, axis=-1).astype(np.float32)
        row2.append(_label(player.render_frame(state, np.broadcast_to(grey, (n,) + grey.shape[1:]), index=i), label))
    write_png(out, np.concatenate([np.concatenate(panels, axis=1), np.concatenate(row2, axis=1)], axis=0))
    player.exposure = None  # the video picks its own
    shadowed = (rad["truth"].sum(-1) < 0.8 * rad["unshadowed"].sum(-1))  # where the truth says "in shadow"
    darker = rad["model"].sum(-1) < rad["unshadowed"].sum(-1)
    from prt_torch.compare.reference import front_facing

    front = front_facing(pos[i], frames[i], eye)  # the reference is 0 behind the horizon (the images hide it)
    return {
        "frames": int(n), "comparison_row": int(rows[i]),
        "vis_rel_err_model": rel(model, truth), "vis_rel_err_unshadowed": rel(hemi, truth),
        "radiance_rel_rmse_model": rel(rad["model"], rad["truth"]),
        "radiance_rel_rmse_unshadowed": rel(rad["unshadowed"], rad["truth"]),
        "shadowed_vertex_fraction": float(shadowed.mean()),
        "model_darker_where_shadowed": float(darker[shadowed].mean()) if shadowed.any() else float("nan"),
        "peaks": player.peaks.to_dict()["peaks"],
        "peak_visibility": None if player.peak_source is None else player.peak_source.kind,
        "reference": {"row": int(rows[i]), "n_rays": 2 * int(reference_rays), "front_facing_vertices": int(front.sum()),
                      **{f"radiance_rel_rmse_{k}": rel(rad[k][i][front], ref[front])
                         for k in ("truth", "model", "unshadowed")}},
    }


def _peak_visibilities(player: Any, ds: Any, state: Any) -> dict[str, np.ndarray]:
    """The peaks' ``(F, V, P)`` visibility of the comparison's columns: ``truth`` exact (Embree to
    :data:`TRUTH_DISC_SIDE` squared samples of the disc),
    ``model`` the player's (:attr:`~prt_torch.player.player.Player.peak_source`), ``unshadowed`` none (the disc's
    share above the horizon). ``{}`` without peaks."""
    from prt_torch.blockers.cones import sphere_visibility_soa
    from prt_torch.player.peaks import ExactPeaks

    if not player.peaks.peaks:
        return {}
    d, a = player._peak_dirs, player.peaks.angular_radii
    f = state.features.shape[0]
    offset = float(dict(ds.attrs.get("bake", {}))["ray_offset_world"])
    exact = ExactPeaks(player.character.faces, offset, side=TRUTH_DISC_SIDE)
    none = sphere_visibility_soa(state.positions, state.normals, np.zeros((f, 0, 3), np.float32),
                                 np.zeros(0, np.float32), d, a)
    return {"truth": exact.vertex_last(state.positions, state.normals, None, d, a),
            "model": player.peak_visibility(state), "unshadowed": none}


def _peak_term(player: Any, state: Any, visibility: np.ndarray | None) -> np.ndarray | float:
    """The peaks' radiance ``(F, V, 3)`` with ``visibility`` (``None``: no peaks, 0)."""
    return 0.0 if visibility is None else player.shade_peaks(state, visibility)


def _reference(player: Any, ds: Any, state: Any, i: int, env: Any, n_rays: int) -> np.ndarray:
    """``(V, 3)`` the Monte-Carlo reference radiance of batch frame ``i`` toward the player's eye (the mean of two
    estimates of ``n_rays`` hemisphere rays each; the residual sky at full resolution and every peak as a disk of
    its angular radius: :func:`prt_torch.compare.reference.split_reference`) with the analytic BRDF of the
    player's RPO."""
    from prt_torch.compare.reference import reference_pair, split_reference
    from prt_torch.player.peaks import AUTO, load_split

    split = player.peaks.split if player.peaks.split is not None else load_split(env, AUTO)
    light = split_reference(split, env)
    offset = float(dict(ds.attrs.get("bake", {}))["ray_offset_world"])
    pos = np.ascontiguousarray(state.positions[i].T, dtype=np.float64)
    frames = state.frames_vx33()[i].astype(np.float64)
    pair = reference_pair(pos, frames, player.character.faces, player.eye, light, {"brdf": player.peak_brdf()},
                          int(n_rays), offset)
    return pair.mean["brdf"].astype(np.float32)


def _label(img: np.ndarray, text: str) -> np.ndarray:
    import cv2

    img = np.ascontiguousarray(img.copy())
    cv2.putText(img, text, (12, 28), cv2.FONT_HERSHEY_SIMPLEX, 0.8, (240, 240, 240), 2, cv2.LINE_AA)
    return img


def play_scene(run: Any, scene: Any, clip: Any, args: Any, hw: tuple[int, int]) -> dict[str, Any]:
    """The held-out video as a scene (:class:`prt_torch.player.scene.ScenePlayer`): floor, cast shadows."""
    from prt_torch.player.scene import ScenePlayer

    sp = ScenePlayer(run, scene=scene, clip=clip, env=args.env, brdf=args.brdf, window_size=hw)
    try:
        return sp.play(out=run.demo_video, max_frames=args.max_frames, timings=run.timings_path(run.demo_video))
    finally:
        sp.close()


def _exact_scene_peaks(run: Any, scene: Any, clip: Any, fps: float, env: Any, brdf: str, hw: tuple[int, int],
                       frame: int) -> Any:
    """The scene's frame ``frame`` computed with exact peak visibility (:class:`~prt_torch.player.scene.ScenePlayer`
    ``peak_kind="exact"``): its ``peak_visibility`` and ``ground_peak_visibility`` are the truth's."""
    from prt_torch.player.scene import ScenePlayer

    sp = ScenePlayer(run, scene=scene, clip=clip, fps=fps, env=env, brdf=brdf, window_size=hw, peak_kind="exact")
    try:
        return sp.compute(frame)
    finally:
        sp.close()


def scene_row(run: Any, ds: Any, scene: Any, clip: str, row: int, fps: float, env: Any, brdf: str,
              hw: tuple[int, int], out: Path) -> dict[str, Any]:
    """A third row for the comparison PNG ``out`` at dataset ``row``: the scene rendered with whole-scene Embree
    truth (with peaks: exact peak visibility too) | the player's composition (model x ground half-space, SHEXP floor;
    the peaks through the player's blockers) | 4x |difference|, one tone map from the truth, under the reference
    column an empty panel. ``clip``: the character clip the row's ``frame_index`` indexes (the held-out entry's
    source, by the one clip-name rule). Returns that frame's figures."""
    from prt_torch.player.scene import SceneFrame, ScenePlayer
    from prt_torch.player.video import write_png
    from prt_torch.scene.scene import pose_actor
    from prt_torch.scene.truth import GROUND_BELOW_HORIZON, GROUND_TRUTH_RAYS, SceneTracer
    from prt_torch.scoring.statistics import image_psnr
    from prt_torch.scoring.strips import abs_diff_image

    frame = int(ds.frame_index[row])
    sp = ScenePlayer(run, scene=scene, clip=clip, fps=fps, env=env, brdf=brdf, window_size=hw)
    try:
        model = sp.compute(frame)
        bake = dict(ds.attrs.get("bake", {}))
        tracer = SceneTracer(sp.order, int(bake["n_rays"]), float(bake["ray_offset_world"]), int(bake.get("seed", 0)))
        posed = [pose_actor(a, a.locals(np.array([frame]), sp.fps)) for a in sp.actors]
        meshes = [(sp.ground.vertices, sp.ground.faces)] + [(p.positions[0], a.character.faces)
                                                             for a, p in zip(sp.actors, posed, strict=True)]
        receivers = [(p.positions[0], p.frames[0], pl.bundle.below_horizon)
                     for p, pl in zip(posed, sp.actor_players, strict=True)]
        receivers.append((sp.ground.vertices, sp.ground.frames(), GROUND_BELOW_HORIZON,
                          max(GROUND_TRUTH_RAYS, tracer.n_rays)))
        tv = tracer.frame(meshes, receivers)
        # the peaks' truth: the same scene with exact peak visibility (Embree to the discs: characters and floor)
        exact = _exact_scene_peaks(run, scene, clip, fps, env, brdf, hw, frame) if sp.n_peaks else None
        char_rad = [pl.shade(st, visibility=v[None], checked=False) for pl, st, v in
                    zip(sp.actor_players, model.states, tv[:-1], strict=True)]
        ground_rad = sp.shade_ground(tv[-1])
        if exact is not None:
            char_rad = [r + pl.shade_peaks(st, pv) for r, pl, st, pv in
                        zip(char_rad, sp.actor_players, model.states, exact.peak_visibility, strict=True)]
            ground_rad = ground_rad + sp.shade_ground_peaks(exact.ground_peak_visibility)
        truth = SceneFrame(model.states, char_rad, [v[None] for v in tv[:-1]], ground_rad, tv[-1],
                           None if exact is None else exact.peak_visibility,
                           None if exact is None else exact.ground_peak_visibility)
        img_t = sp.render(truth)  # fixes the one tone map from the truth
        img_m = sp.render(model)
        from prt_torch.scoring.images import ImageRenderer

        bg = np.round(np.asarray(ImageRenderer.BACKGROUND) * 255.0)
        mask = np.abs(img_t.astype(np.float64) - bg).max(-1) > 1.0  # the scene's pixels (not the background)
        psnr = image_psnr(img_m, img_t, mask) if mask.any() else float("nan")
        blank = np.empty_like(img_t)
        blank[:] = bg.astype(np.uint8)  # under the reference column
        row3 = np.concatenate([blank, _label(img_t, "scene: Embree truth"),
                               _label(img_m, "scene: model + SHEXP floor"),
                               _label(abs_diff_image(img_m, img_t), "4x |difference|")], axis=1)
        self_only = sp.actor_players[0].visibility(model.states[0].features)
    finally:
        sp.close()
    import imageio.v2 as iio

    prev = iio.imread(out)
    write_png(out, np.concatenate([prev, row3], axis=0))

    def rel(a: np.ndarray, b: np.ndarray) -> float:
        return float(np.linalg.norm(a - b) / max(np.linalg.norm(b), 1e-12))

    return {"frame_index": frame, "characters": len(model.states), "ground_vertices": int(len(tv[-1])),
            "ground_vis_rel_err": rel(model.ground_visibility, tv[-1]),
            "ground_radiance_rel_rmse": rel(model.ground_radiance, truth.ground_radiance),
            "scene_psnr_image": psnr,
            "vis_rel_err_in_scene": rel(model.visibility[0][0], tv[0]),
            "vis_rel_err_self_only": rel(self_only[0], tv[0])}

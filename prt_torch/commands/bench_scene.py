"""``prt bench scene [RUN]``: whole-scene frames/s (floor + characters, cast shadows) side by side with the plain
player, interleaved frame by frame in one process (the machine is shared: only side-by-side ratios and medians mean
anything).

Configurations, each a :class:`~prt_torch.player.scene.ScenePlayer` (or the plain ``Player`` for the baseline) on
the same frames of the run's held-out clip, compute path only (posing, models, SHEXP, composition, shading; no
rendering):

* ``player``: the plain :class:`~prt_torch.player.Player` (split graphs), one character, no floor;
* ``scene_1``: one character, no floor (the scene machinery's overhead);
* ``scene_1_floor``: one character on a 64 x 64 floor (SHEXP floor, half-space composition);
* ``scene_2_floor``: two characters on the floor (``--scene``, default ``configs/scene2.yaml``: SHEXP of the other
  character at each character's vertices too);
* with peak lights (``--peaks``, default ``auto``: the sky's sun; the player and every scene shade the residual on
  the SH path plus the peaks' term, :mod:`prt_torch.player.scene`): also ``scene_1_floor_no_peaks`` and
  ``scene_2_floor_no_peaks``, the same scenes with ``--peaks 0`` (the whole lighting on the SH path, no peak
  shadows), for the peaks' cost side by side.

Reported: median ms and frames/s of each, the per-step medians of the scene ones (``pose``, ``characters``,
``ground``), and ``ratio_vs_player`` (frame time / the player's).

``--characters K``: instead, the floor + ``K`` copies of the run's character on a square grid
(:func:`grid_scene`: spaced by 1.5 x the rest mesh's horizontal extent so that no two meet, each a quarter of the
clip later than the previous), timed alone; prints ``{"fps", "characters", "steps", ...}`` (``steps``: the
per-step median ms).
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path
from typing import Any

import numpy as np

HELP = "Whole-scene frames/s (floor + 1 or 2 characters, cast shadows) next to the plain player, in one run."


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("run", nargs="?", default="runs/demo", help="exported run (default runs/demo; `prt demo`)")
    parser.add_argument("--frames", type=int, default=20, help="timed frames per configuration (default 20)")
    parser.add_argument("--scene", default=None, help="two-character scene YAML (default configs/scene2.yaml)")
    parser.add_argument("--clip", default=None, help="clip of the one-character scenes (default: held-out clip)")
    parser.add_argument("--threads", type=int, default=2, help="onnxruntime intra-op threads")
    parser.add_argument("--peaks", default="auto", help="peak lights of every configuration: auto|0|K (default auto; "
                                                        "not 0: the *_no_peaks scenes too)")
    parser.add_argument("--characters", type=int, default=None,
                        help="time the floor + K copies of the run's character on a grid instead (1..64)")
    parser.add_argument("--json", action="store_true", help="print the JSON only")


def run(args: argparse.Namespace) -> int:
    from prt_torch import limits
    from prt_torch.commands import _validate as V
    from prt_torch.player import Player
    from prt_torch.player.peaks import check_peaks_arg
    from prt_torch.player.scene import SCENE_STEPS, ScenePlayer
    from prt_torch.player.timing import FrameTimer
    from prt_torch.progress import make_console
    from prt_torch.rundir import RunDir
    from prt_torch.scene.config import scene_from_dict
    from prt_torch.scene.load import load_scene

    limits.check_int(args.frames, "--frames", 1, 100_000)
    limits.check_int(args.threads, "--threads", 1, limits.MAX_THREADS)
    peaks = check_peaks_arg(args.peaks)
    V.input_dir(args.run, "run directory")
    scene_path = args.scene or str(Path(__file__).resolve().parents[2] / "configs" / "scene2.yaml")
    V.input_file(scene_path, "--scene")
    two = load_scene(scene_path)
    run_dir = RunDir(args.run)
    clip = args.clip or _heldout_clip(run_dir)
    console = make_console(stderr=True)
    if args.characters is not None:
        limits.check_int(args.characters, "--characters", 1, 64)
        return _bench_grid(run_dir, clip, args, peaks, console)
    one = scene_from_dict({"characters": [{"clip": clip}]})
    one_floor = scene_from_dict({"ground": {}, "characters": [{"clip": clip}]})
    two_floor = two if two.ground is not None else two.model_copy(update={"ground": one_floor.ground})
    kw: dict[str, Any] = {"threads": args.threads, "window_size": (240, 320), "peaks": peaks}
    player = Player(run_dir, graph="split", threads=args.threads, peaks=peaks)
    scenes = {"scene_1": ScenePlayer(run_dir, scene=one, **kw), "scene_1_floor": ScenePlayer(run_dir, scene=one_floor,
                                                                                               **kw),
              "scene_2_floor": ScenePlayer(run_dir, scene=two_floor, clip=clip, **kw)}
    if peaks != 0:
        kw0 = {**kw, "peaks": 0}
        scenes["scene_1_floor_no_peaks"] = ScenePlayer(run_dir, scene=one_floor, **kw0)
        scenes["scene_2_floor_no_peaks"] = ScenePlayer(run_dir, scene=two_floor, clip=clip, **kw0)
    try:
        locals_ = player.clip_locals(clip, scenes["scene_1"].fps)
        n = min(args.frames, min(sp.n_frames for sp in scenes.values()), len(locals_))
        timers = {name: FrameTimer() for name in scenes}
        p_secs: list[float] = []
        for sp in scenes.values():  # warm-up (first-call allocations, ORT arenas)
            sp.compute(0)
        player.compute(locals_[:1])
        for i in range(n):
            t0 = time.perf_counter()
            player.compute(locals_[i:i + 1])
            p_secs.append(time.perf_counter() - t0)
            for name, sp in scenes.items():
                t0 = time.perf_counter()
                sp.compute(i, timers[name])
                timers[name].add("frame", time.perf_counter() - t0)
        p_ms = float(np.median(p_secs) * 1e3)
        out: dict[str, Any] = {"run": str(run_dir.path), "clip": clip, "frames": n, "scene_file": scene_path,
                               "player": {"ms": p_ms, "fps": 1e3 / p_ms, "peaks": len(player.peaks.peaks)}}
        for name, sp in scenes.items():
            s = timers[name].summary(("frame",))
            ms = s["compute_ms_median"]
            out[name] = {"ms": ms, "fps": 1e3 / ms, "ratio_vs_player": ms / p_ms,
                         "characters": len(sp.actors), "ground_vertices": 0 if sp.ground is None else
                         sp.ground.n_vertices, "vertices": int(sum(a.character.num_vertices for a in sp.actors)),
                         "peaks": sp.n_peaks, "peak_visibility": sp.peak_kind,
                         "steps_ms": {k: s["steps_ms"][k]["median"] for k in SCENE_STEPS if k in s["steps_ms"]}}
    finally:
        player.close()
        for sp in scenes.values():
            sp.close()
    if args.json:
        print(json.dumps(out, indent=1))
        return 0
    console.print(f"[bold]prt bench scene[/] {run_dir.path} ({clip}, {n} frames, compute path, medians)")
    console.print(f"  player (1 character, no floor): {p_ms:.1f} ms = {1e3 / p_ms:.1f} frames/s")
    for name in scenes:
        o = out[name]
        steps = ", ".join(f"{k} {v:.1f}" for k, v in o["steps_ms"].items())
        console.print(f"  {name}: {o['ms']:.1f} ms = {o['fps']:.1f} frames/s ({o['ratio_vs_player']:.2f}x the "
                      f"player; {o['characters']} character(s), floor {o['ground_vertices']} vertices; ms: {steps})")
    print(json.dumps(out))
    return 0


def grid_scene(character: Any, clip: str, k: int, clip_seconds: float) -> Any:
    """A floor + ``k`` copies of ``character`` playing ``clip`` on a square grid: spaced by 1.5 x the rest mesh's
    horizontal extent (no two characters meet however they move within their own footprint), each a quarter of the
    clip (``clip_seconds``) later than the previous."""
    import math

    from prt_torch.scene.config import scene_from_dict

    rest = np.asarray(character.rest_vertices)
    step = 1.5 * float(np.ptp(rest[:, :2], axis=0).max())
    cols = math.ceil(math.sqrt(k))
    chars = [{"clip": clip, "offset": [step * (i % cols), step * (i // cols), 0.0],
              "time_offset": (0.25 * i * clip_seconds) % max(clip_seconds, 1e-9)} for i in range(k)]
    return scene_from_dict({"ground": {}, "characters": chars})


def _bench_grid(run_dir: Any, clip: str, args: argparse.Namespace, peaks: Any, console: Any) -> int:
    """``--characters K``: the floor + K characters (:func:`grid_scene`), timed alone."""
    from prt_torch.player.scene import SCENE_STEPS, ScenePlayer
    from prt_torch.player.timing import FrameTimer

    ch = run_dir.character()
    c = ch.clip(clip)
    scene = grid_scene(ch, clip, args.characters, c.num_frames / c.fps)
    sp = ScenePlayer(run_dir, scene=scene, threads=args.threads, window_size=(240, 320), peaks=peaks)
    try:
        timer = FrameTimer()
        sp.compute(0)  # warm-up
        n = min(args.frames, sp.n_frames)
        for i in range(n):
            t0 = time.perf_counter()
            sp.compute(i, timer)
            timer.add("frame", time.perf_counter() - t0)
        s = timer.summary(("frame",))
        ms = s["compute_ms_median"]
        out = {"fps": 1e3 / ms, "characters": len(sp.actors), "ms": ms, "frames": n, "clip": clip,
               "run": str(run_dir.path), "peaks": sp.n_peaks, "peak_visibility": sp.peak_kind,
               "ground_vertices": 0 if sp.ground is None else sp.ground.n_vertices,
               "vertices": int(sum(a.character.num_vertices for a in sp.actors)),
               "steps": {k: s["steps_ms"][k]["median"] for k in SCENE_STEPS if k in s["steps_ms"]}}
    finally:
        sp.close()
    if not args.json:
        steps = ", ".join(f"{k} {v:.1f}" for k, v in out["steps"].items())
        console.print(f"[bold]prt bench scene[/] {run_dir.path}: floor + {out['characters']} character(s) "
                      f"({clip}, {n} frames, compute path, medians): {ms:.1f} ms = {out['fps']:.1f} frames/s "
                      f"(ms: {steps})")
    print(json.dumps(out))
    return 0


def _heldout_clip(run: Any) -> str:
    """The character clip of the run's first held-out entry (else ``wave``; also without a dataset): its source by
    the one clip-name rule (:meth:`prt_torch.bake.store.BakedDataset.clip_by_name`), since a scene names clips of
    the character (a within-clip split's entry is a frame range of one)."""
    from prt_torch.errors import MissingArtifact

    try:
        ds = run.dataset()
    except MissingArtifact:
        return "wave"
    cfg = ds.run_config()
    held = cfg.character.heldout_clips if cfg is not None else []
    if held:
        from prt_torch.rig.config import as_clip_range

        return ds.clip_by_name(as_clip_range(held[0]).dataset_name, run.character()).source
    return "wave"

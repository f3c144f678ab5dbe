"""``prt play RUN --clip NAME | --motion FILE.bvh | --scene FILE [--env FILE] [--brdf NAME] [--out video.mp4]``:
onnxruntime playback (a motion file is retargeted onto the run's character by :mod:`prt_torch.rig.retarget`,
torch-free)."""

from __future__ import annotations

import argparse
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from prt_torch.rig.character import Character
    from prt_torch.rig.clip import Clip
    from prt_torch.rundir import RunDir

HELP = "Play a clip of an exported run with onnxruntime: offscreen MP4/PNG frames or a window; frame timings."


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from prt_torch.player.renderers import renderers

    parser.add_argument("run", help="exported run directory (runs/NAME)")
    parser.add_argument("--clip", default=None, help="clip name of the character (e.g. walk) or of the run's "
                                                     "split (e.g. a held-out frame range of a training clip)")
    parser.add_argument("--sequence", default=None, help="a deformable (cloth) run: the sequence of its vertex cache "
                                                         "to play (prt_torch.cloth.player)")
    parser.add_argument("--motion", default=None, help="a motion file (.bvh, or a humanoid .glb/.gltf) retargeted "
                                                       "onto the run's character, instead of --clip")
    parser.add_argument("--motion-fps", type=float, default=None,
                        help="retarget the motion at this rate (default: the character's clips' rate)")
    parser.add_argument("--env", default=None, help="HDR environment map (.hdr/.exr/.pfm); default: procedural sky")
    parser.add_argument("--brdf", default=None, help="BRDF name from the run's RPO catalogue, 'material' (the "
                                                     "character's own material: Cook-Torrance with its roughness, "
                                                     "built once and cached in the run), or an RPO .npz; default: "
                                                     "'material' for a glTF character with a material, else the "
                                                     "catalogue's first")
    parser.add_argument("--out", default=None, help="write an MP4 here (offscreen)")
    parser.add_argument("--png", default=None, help="write PNG frames into this directory (offscreen)")
    parser.add_argument("--max-frames", "--frames", dest="max_frames", type=int, default=None,
                        help="play at most this many frames")
    parser.add_argument("--fps", type=float, default=None, help="resample the clip to this rate")
    parser.add_argument("--camera", default=None, choices=["follow", "fixed"],
                        help="--clip / --motion: follow (default): frame the posed character over a window of "
                             "+-0.5 s, smoothly (prt_torch.player.follow: root motion stays in the frame); fixed: the "
                             "rest pose's box")
    parser.add_argument("--graph", default=None,
                        choices=["compiled", "fused", "split", "overlap", "fused_peaks", "pipeline"],
                        help="default: compiled on the CPU (a small ORT graph, then one compiled decode + shade "
                             "pass) when the export ships it, else fused; or one fused ORT graph, visibility then "
                             "shading, visibility on a worker thread "
                             "overlapping the numpy posing (best when a core is free), the fused graph with the "
                             "peak lights and their learned shadows inside it (fused_peaks.onnx), or (a cloth "
                             "sequence) the next frame's features, visibility and frames on a worker while this one "
                             "is shaded")
    parser.add_argument("--threads", type=int, default=2, help="onnxruntime intra-op threads")
    parser.add_argument("--device", default="cpu", choices=["cpu", "cuda"],
                        help="onnxruntime device: cuda needs onnxruntime-gpu (extra 'gpu') and a CUDA GPU")
    parser.add_argument("--size", default="480x640", help="image size HxW (default 480x640; each side 1..8192)")
    parser.add_argument("--timings", default=None, help="frame timings JSON (default: next to --out, or "
                                                        "a timings file in RUN)")
    parser.add_argument("--light-angle", type=float, default=0.0, help="rotate the lighting about z (degrees)")
    parser.add_argument("--peaks", default="auto",
                        help="peak lights split off the lighting, each with its own soft shadow: 'auto' (the sky's "
                             "sun, or up to 2 of a map's), 0 (none: the whole lighting through SH, as before) or K in "
                             "1..4")
    parser.add_argument("--peak-visibility", default=None,
                        help="the peaks' shadows: exact (Embree rays to the disc), spheres (the run's blocker "
                             "spheres) or learned (the run's learned peak blockers); default learned when the run "
                             "has them, else spheres, else no shadow")
    table = renderers()  # onnx and the method packages' (prt_torch.player.renderers.RENDERERS)
    parser.add_argument("--renderer", default="onnx", choices=[n for r in table for n in r.names],
                        help="; ".join(r.help for r in table))
    for r in table:  # each renderer's own options (prt_torch.player.renderers.Renderer.add_arguments)
        if r.add_arguments is not None:
            r.add_arguments(parser)
    parser.add_argument("--ground", action="store_true", help="a floor under the character(s), with cast shadows "
                                                              "(prt_torch.player.scene)")
    parser.add_argument("--scene", default=None, help="a scene YAML (scene: ground, characters), e.g. "
                                                      "configs/scene2.yaml; default: the run's recorded scene")


def run(args: argparse.Namespace) -> int:
    import math

    from prt_torch import limits
    from prt_torch.commands import _validate as V
    from prt_torch.errors import PrtError

    # every argument is checked before anything is loaded or written
    h, w = limits.parse_size(args.size)
    if args.fps is not None:
        limits.check_float(args.fps, "--fps", 0.0, limits.MAX_FPS, lo_open=True)
    if args.max_frames is not None:
        limits.check_int(args.max_frames, "--max-frames", 1, limits.MAX_FRAMES)
    limits.check_int(args.threads, "--threads", 1, limits.MAX_THREADS)
    if not math.isfinite(args.light_angle):
        raise PrtError(f"--light-angle must be a finite number of degrees, got {args.light_angle}")
    if args.clip is not None and args.motion is not None:
        raise PrtError("give --clip NAME or --motion FILE, not both")
    from prt_torch.player.peaks import PEAK_KINDS, check_peaks_arg

    args.peaks = check_peaks_arg(args.peaks)
    if args.peak_visibility is not None and args.peak_visibility not in PEAK_KINDS:
        raise PrtError(f"--peak-visibility: unknown kind {args.peak_visibility!r}: expected one of "
                       f"{', '.join(PEAK_KINDS)}")
    if args.clip is None and args.motion is None and getattr(args, "scene", None) is None \
            and getattr(args, "sequence", None) is None:
        raise PrtError("give exactly one of --clip NAME or --motion FILE")  # a --scene file may name its clips
    if args.clip is not None and not args.clip.strip():
        raise PrtError("--clip: empty clip name")
    if args.motion is not None:
        V.input_file(args.motion, "--motion")
    if args.motion_fps is not None:
        limits.check_float(args.motion_fps, "--motion-fps", 0.0, limits.MAX_FPS, lo_open=True)
    V.input_dir(args.run, "run directory")
    if args.env is not None:
        V.input_file(args.env, "--env")
    if args.brdf is not None and args.brdf.lower().endswith(".npz"):
        V.input_file(args.brdf, "--brdf")
    if args.out is not None:
        V.output_file(args.out, "--out")
    if args.png is not None:
        V.output_dir(args.png, "--png")
    if args.timings is not None:
        V.output_file(args.timings, "--timings")
    if getattr(args, "camera", None) is not None and (getattr(args, "sequence", None) is not None or args.ground
                                                      or getattr(args, "scene", None) is not None):
        raise PrtError("--camera frames a --clip or --motion; a --sequence or --ground/--scene keeps its own camera")
    if getattr(args, "sequence", None) is not None:
        return _play_sequence(args, h, w)

    if args.ground or args.scene is not None:
        return _play_scene(args, h, w)

    import numpy as np

    from prt_torch.player.render import has_display
    from prt_torch.player.renderers import renderer
    from prt_torch.progress import make_console

    console = make_console(stderr=True)
    show = args.out is None and args.png is None
    if show and not has_display():
        raise PrtError("no display: pass --out video.mp4 or --png DIR to render offscreen")
    from prt_torch.rundir import RunDir

    run = RunDir(args.run)
    timings = args.timings or (run.timings_path(args.out) if args.out else run.play_timings)
    player = renderer(args.renderer).build(args, (h, w))  # prt_torch.player.renderers: onnx and the methods'
    if args.light_angle:
        player.rotate_light(np.radians(args.light_angle))
    clip: Any = None if args.clip is None else _clip_of_run(run, player.character, args.clip)
    try:
        if args.motion is not None:
            from prt_torch.rig.retarget import retarget_file

            motion, report = retarget_file(args.motion, player.character, fps=args.motion_fps)
            clip = f"motion:{motion.name}"
            player.character.clips[clip] = motion
            console.print(report.summary())
        res = player.play(clip, out=args.out, png_dir=args.png, max_frames=args.max_frames, fps=args.fps,
                          timings=timings, show=show, camera=getattr(args, "camera", None) or "follow")
    finally:
        player.close()
    s = res.summary
    console.print(f"{res.frames} frames: compute path {s.get('compute_fps', 0):.0f} frames/s "
                  f"({s.get('compute_ms_median', 0):.2f} ms), with rendering {s.get('total_fps', 0):.1f} frames/s")
    for p in res.outputs:
        console.print(f"wrote {p}")
    return 0


def _clip_of_run(run: RunDir, character: Character, name: str) -> Clip:
    """``--clip NAME`` as the run uses it: one of its dataset's clips (a split entry, e.g. a held-out frame range of
    a training clip) or a clip of the character, by the one rule
    (:meth:`prt_torch.bake.store.BakedDataset.clip_by_name`; a run without its dataset: the character's clips,
    :func:`prt_torch.rig.load.clip_by_name`)."""
    if run.dataset_path.is_dir():
        return run.dataset().clip_by_name(name, character).clip
    from prt_torch.rig.load import clip_by_name

    return clip_by_name(character, name).clip


def _play_sequence(args: argparse.Namespace, h: int, w: int) -> int:
    """``--sequence NAME``: a cached sequence of a deformable run
    (:class:`~prt_torch.cloth.player.DeformablePlayer`, graph ``pipeline`` (default), ``split`` or
    ``overlap``)."""
    import numpy as np

    from prt_torch.cloth.player import DeformablePlayer
    from prt_torch.errors import PrtError
    from prt_torch.player.render import has_display
    from prt_torch.progress import make_console
    from prt_torch.rundir import RunDir

    for flag, value in (("--clip", args.clip), ("--motion", args.motion), ("--scene", args.scene)):
        if value is not None:
            raise PrtError(f"give --sequence NAME or {flag}, not both")
    if args.ground or args.renderer != "onnx":
        raise PrtError("--sequence plays the run's learned models (--renderer onnx) without --ground")
    if not args.sequence.strip():
        raise PrtError("--sequence: empty sequence name")
    show = args.out is None and args.png is None
    if show and not has_display():
        raise PrtError("no display: pass --out video.mp4 or --png DIR to render offscreen")
    run = RunDir(args.run)
    timings = args.timings or (run.timings_path(args.out) if args.out else run.play_timings)
    # a sequence plays pipelined by default (the next frame's features + visibility + frames on a worker while this
    # one is shaded: 504 vs 274 frames/s split on the 7.7k flag, same radiance) unless --graph split / overlap;
    # its fused graph (measured slower: the cluster order costs a permutation in and out) is DeformablePlayer(graph=
    # "fused")
    graph = "pipeline" if args.graph in (None, "fused") else args.graph
    console = make_console(stderr=True)
    player = DeformablePlayer(args.run, env=args.env, brdf=args.brdf, graph=graph, threads=args.threads,
                              window_size=(h, w), device=args.device)
    visibility = "local network" if player.local_graph is not None else "dihedral angles + pose graph"
    try:
        if args.light_angle:
            player.rotate_light(np.radians(args.light_angle))
        res = player.play(args.sequence, out=args.out, png_dir=args.png, max_frames=args.max_frames, fps=args.fps,
                          timings=timings, show=show)
    finally:
        player.close()
    s = res.summary
    console.print(f"{res.frames} frames of {args.sequence!r} ({graph}): compute path {s.get('compute_fps', 0):.0f} "
                  f"frames/s ({s.get('compute_ms_median', 0):.2f} ms: frames + {visibility} + shading), with rendering "
                  f"{s.get('total_fps', 0):.1f} frames/s")
    for p in res.outputs:
        console.print(f"wrote {p}")
    return 0


def _play_scene(args: argparse.Namespace, h: int, w: int) -> int:
    """``--ground`` / ``--scene``: :class:`prt_torch.player.scene.ScenePlayer` (offscreen only)."""
    from prt_torch.errors import PrtError
    from prt_torch.player.scene import ScenePlayer
    from prt_torch.progress import make_console
    from prt_torch.rundir import RunDir
    from prt_torch.scene.load import load_scene

    if args.renderer != "onnx":
        raise PrtError(f"--ground/--scene play the run's learned models (--renderer onnx), not --renderer "
                       f"{args.renderer}")
    if args.out is None and args.png is None:
        raise PrtError("--ground/--scene render offscreen: pass --out video.mp4 or --png DIR")
    if args.scene is not None:
        from prt_torch.commands import _validate as V

        V.input_file(args.scene, "--scene")
    scene = load_scene(args.scene) if args.scene is not None else None
    run = RunDir(args.run)
    timings = args.timings or (run.timings_path(args.out) if args.out else run.play_timings)
    console = make_console(stderr=True)
    clip: Any = args.clip  # a name the character has stays a name: each scene character looks it up in its own clips
    if clip is not None and clip not in (character := run.character()).clips:
        clip = _clip_of_run(run, character, clip)  # a split's clip (e.g. a held-out frame range of a clip)
    player = ScenePlayer(args.run, scene=scene, ground=args.ground, clip=clip, fps=args.fps, env=args.env,
                         brdf=args.brdf, threads=args.threads, window_size=(h, w), peaks=args.peaks,
                         peak_kind=args.peak_visibility, motion=args.motion, motion_fps=args.motion_fps)
    for _, report in player.motions.values():
        console.print(report.summary())
    try:
        if args.light_angle:
            import numpy as np

            for p in player.players.values():
                p.rotate_light(np.radians(args.light_angle))
        res = player.play(out=args.out, png_dir=args.png, max_frames=args.max_frames, timings=timings)
    finally:
        player.close()
    console.print(f"{res['frames']} scene frames ({len(player.actors)} character(s), "
                  f"{'a' if player.ground is not None else 'no'} floor): compute path "
                  f"{res.get('compute_fps', 0):.0f} frames/s, with rendering {res.get('total_fps', 0):.1f} frames/s")
    for p in res["outputs"]:
        console.print(f"wrote {p}")
    return 0

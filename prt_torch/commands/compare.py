"""``prt compare RUN``: every visibility method side by side on the shipping path (schema: :mod:`prt_torch.compare`)."""

from __future__ import annotations

import argparse
import json

HELP = "Compare visibility methods (truth, unshadowed, learned models) on held-out frames or a clip."


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("run", help="trained run directory (runs/NAME)")
    parser.add_argument("--methods", default=None, help="comma-separated methods (default: every available one; "
                                                        "sh_truth is always included)")
    parser.add_argument("--clip", default=None, help="a clip of the character to pose and trace (default: the "
                                                     "dataset's held-out frames)")
    parser.add_argument("--motion", default=None, help="a motion file (.bvh, or a humanoid .glb/.gltf) retargeted "
                                                       "onto the character, posed and traced instead of --clip")
    parser.add_argument("--motion-fps", type=float, default=None, help="resample the motion to this rate")
    parser.add_argument("--frames", type=int, default=None, help="at most this many frames (evenly spaced)")
    parser.add_argument("--env", default=None, help="HDR environment map (default: the player's procedural sky)")
    parser.add_argument("--light", default="sky", choices=["sky", "smooth", "sun"],
                        help="sky: the player's lighting (--env, or the procedural sky + its sun); smooth: --env or "
                             "the sky without its sun; sun: that plus a small bright sun disk (sharp lighting)")
    parser.add_argument("--sun-size", type=float, default=None,
                        help="--light sun: the sun's half-angle in degrees (default 2)")
    parser.add_argument("--sun-power", type=float, default=None,
                        help="--light sun: the sun's power, irradiance on a facing surface (default 8: the player's)")
    parser.add_argument("--peaks", default="auto",
                        help="auto|0|K: split the light into up to K peak lights (suns) + the residual; every "
                             "visibility method gains <method>+peaks_<kind> rows (default auto: the sky's or --light "
                             "sun's sun, a map's detected peaks; 0: no split)")
    parser.add_argument("--peak-kinds", default=None,
                        help="comma-separated peak visibilities of the +peaks rows, each for every visibility method "
                             "(exact, spheres, learned; default: spheres and learned where the run has them, plus "
                             "exact for sh_truth)")
    parser.add_argument("--image-frames", type=int, default=8, help="frames rendered for image PSNR (default 8)")
    parser.add_argument("--reference-frames", type=int, default=4,
                        help="frames of the Monte-Carlo reference (default 4; 0 disables)")
    parser.add_argument("--reference-rays", type=int, default=512,
                        help="rays per vertex of each of the two reference estimates (default 512)")
    parser.add_argument("--threads", type=int, default=2, help="onnxruntime threads (default 2)")
    parser.add_argument("--json", action="store_true", help="print the JSON (schema: prt_torch.compare)")


def run(args: argparse.Namespace) -> int:
    from prt_torch import limits
    from prt_torch.commands import _validate as V
    from prt_torch.compare.methods import METHODS
    from prt_torch.compare.run import run_compare, table_markdown
    from prt_torch.errors import PrtError
    from prt_torch.progress import make_console
    from prt_torch.rundir import RunDir

    methods = V.names(args.methods, "--methods", tuple(METHODS), what="method") if args.methods is not None else None
    if args.frames is not None:
        limits.check_int(args.frames, "--frames", 1, limits.MAX_FRAMES)
    limits.check_int(args.image_frames, "--image-frames", 0, limits.MAX_FRAMES)
    limits.check_int(args.reference_frames, "--reference-frames", 0, limits.MAX_FRAMES)
    limits.check_int(args.threads, "--threads", 1, limits.MAX_THREADS)
    limits.check_int(args.reference_rays, "--reference-rays", 1, limits.MAX_RAYS)
    if args.clip is not None and not args.clip.strip():
        raise PrtError("--clip: empty clip name")
    if args.clip is not None and args.motion is not None:
        raise PrtError("give --clip NAME or --motion FILE, not both")
    if args.motion is not None:
        V.input_file(args.motion, "--motion")
    if args.motion_fps is not None:
        limits.check_float(args.motion_fps, "--motion-fps", 0.0, limits.MAX_FPS, lo_open=True)
    if args.env is not None:
        V.input_file(args.env, "--env")
    if args.sun_size is not None:
        limits.check_float(args.sun_size, "--sun-size", 0.05, 30.0)
    if args.sun_power is not None:
        limits.check_float(args.sun_power, "--sun-power", 0.0, 1e6, lo_open=True)
    if args.light != "sun" and (args.sun_size is not None or args.sun_power is not None):
        raise PrtError("--sun-size and --sun-power need --light sun")
    from prt_torch.player.peaks import PEAK_KINDS, check_peaks_arg

    peaks = check_peaks_arg(args.peaks)
    kinds = V.names(args.peak_kinds, "--peak-kinds", PEAK_KINDS, what="peak kind") \
        if args.peak_kinds is not None else None
    if kinds is not None and peaks == 0:
        raise PrtError("--peak-kinds needs peaks (--peaks auto or K >= 1), got --peaks 0")
    if args.light == "smooth" and peaks not in ("auto", 0):
        raise PrtError(f"--peaks {peaks}: --light smooth has no peak light (use --light sky or sun)")
    V.input_dir(args.run, "run directory")
    console = make_console(stderr=True)
    result = run_compare(args.run, methods=methods, clip=args.clip, max_frames=args.frames, env=args.env,
                         image_frames=args.image_frames, reference_frames=args.reference_frames,
                         reference_rays=args.reference_rays, threads=args.threads, log=console.log,
                         progress=not args.json, motion=args.motion, motion_fps=args.motion_fps,
                         light=args.light, sun_size=args.sun_size, sun_power=args.sun_power, peaks=peaks,
                         peak_kinds=kinds)
    if args.json:
        print(json.dumps(json.loads(json.dumps(result, default=float)), indent=2))
        return 0
    console.print(table_markdown(result))
    console.print(f"wrote {RunDir(args.run).compare_dir}")
    return 0

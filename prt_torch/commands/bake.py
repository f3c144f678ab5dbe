"""``prt bake CONFIG``: ray-trace the ground-truth visibility dataset of a run (resumable)."""

from __future__ import annotations

import argparse
import json

HELP = "Bake ground-truth SH visibility (Embree) into the dataset of runs/NAME; re-running resumes."


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("config", help="run config (YAML), e.g. configs/builtin.yaml")
    parser.add_argument("--run-dir", default=None, help="output run directory (default: runs/<name>)")
    parser.add_argument("--workers", type=int, default=None,
                        help="local worker processes, >= 1 (default: bake.workers, where 0 = one per core; "
                             "1 = in-process)")
    parser.add_argument("--scheduler", default=None,
                        help="Dask scheduler address tcp://HOST:PORT (default: bake.scheduler; local pool if unset)")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    parser.add_argument("--json", action="store_true", help="print a JSON summary (frames, rays, timings)")


def run(args: argparse.Namespace) -> int:
    from prt_torch import limits
    from prt_torch.bake.runner import run_bake
    from prt_torch.commands import _validate as V
    from prt_torch.errors import PrtError
    from prt_torch.progress import make_console

    if args.workers is not None:
        limits.check_int(args.workers, "--workers", 1, limits.MAX_WORKERS)
    if args.scheduler is not None:
        try:
            limits.check_scheduler(args.scheduler)
        except ValueError as exc:
            raise PrtError(f"--scheduler: {exc}") from None
    cfg = V.run_config(args.config, args.run_dir)
    res = run_bake(cfg, workers=args.workers, scheduler=args.scheduler, progress=not args.no_progress)
    summary = {"dataset": str(res.path), "frames": res.frames, "skipped": res.skipped, "rays": res.rays,
               "seconds": round(res.seconds, 3), "frames_per_s": round(res.frames_per_s, 3),
               "rays_per_s": round(res.rays_per_s, 1), "repaired": res.repaired}
    if args.json:
        print(json.dumps(summary, indent=2, sort_keys=True))
    else:
        make_console(stderr=True).print(
            f"baked {res.frames} frames ({res.skipped} already done) in {res.seconds:.1f} s: "
            f"{res.frames_per_s:.2f} frames/s, {res.rays_per_s / 1e6:.2f} Mrays/s -> {res.path}")
    return 0

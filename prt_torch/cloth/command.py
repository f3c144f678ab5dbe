"""``prt simulate CONFIG``: simulate a cloth run's sequences into its vertex cache ``runs/NAME/simulation.zarr``."""

from __future__ import annotations

import argparse
import json

HELP = "Simulate the cloth of a deformable run (MuJoCo) into its vertex cache (runs/NAME); re-running resumes."


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("config", help="run config (YAML) with a cloth: section, e.g. configs/flag.yaml")
    parser.add_argument("--run-dir", default=None, help="output run directory (default: runs/<name>)")
    parser.add_argument("--progress", action=argparse.BooleanOptionalAction, default=True,
                        help="show a progress bar (default: on)")
    parser.add_argument("--json", action="store_true", help="print a JSON summary")


def run(args: argparse.Namespace) -> int:
    import time

    from prt_torch.cloth.cache import VertexCache
    from prt_torch.cloth.simulate import simulate
    from prt_torch.commands import _validate as V
    from prt_torch.errors import PrtError
    from prt_torch.progress import make_console
    from prt_torch.rundir import RunDir

    cfg = V.run_config(args.config, args.run_dir)
    if getattr(cfg, "cloth", None) is None:
        raise PrtError(f"{args.config}: no cloth: section (prt simulate is for deformable runs)")
    t0 = time.perf_counter()
    with RunDir(cfg.out_dir).lock("simulate"):
        path = simulate(cfg, progress=args.progress)
    cache = VertexCache(path)
    summary = {"cache": str(path), "sequences": cache.sequences(), "vertices": cache.n_vertices,
               "seconds": round(time.perf_counter() - t0, 3)}
    if args.json:
        print(json.dumps(summary, indent=2, sort_keys=True))
    else:
        make_console(stderr=True).print(f"simulated {len(summary['sequences'])} sequences ({cache.n_vertices} "
                                        f"vertices) in {summary['seconds']:.1f} s -> {path}")
    return 0

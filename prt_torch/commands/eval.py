"""``prt eval RUN``: errors of every trained model against the baked ground truth, with a report."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

HELP = "Evaluate a trained run on held-out clips: errors, PSNR, jitter, storage; writes RUN/report/."


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("run", help="run directory (runs/NAME) with model.json, or a run config YAML")
    parser.add_argument("--dataset", default=None, help="dataset.zarr (default: the one recorded in model.json)")
    parser.add_argument("--frames", type=int, default=32, help="max frames per split (contiguous per clip)")
    parser.add_argument("--no-report", action="store_true", help="skip figures and the shaded image")
    parser.add_argument("--json", action="store_true", help="print models.<kind>.<split>.<metric> and storage")


def run(args: argparse.Namespace) -> int:
    from rich.console import Console
    from rich.table import Table

    from prt_torch.errors import PrtError
    from prt_torch.eval.evaluate import evaluate_run
    from prt_torch.eval.report import json_summary, write_report
    from prt_torch.io import atomic_write_json

    run_dir = Path(args.run)
    if run_dir.suffix in (".yaml", ".yml"):
        from prt_torch.config import load_config

        run_dir = Path(load_config(run_dir).out_dir)
    if not run_dir.is_dir():
        raise PrtError(f"run directory not found: {run_dir}")
    if args.frames < 2:
        raise PrtError(f"--frames must be >= 2, got {args.frames}")
    console = Console(stderr=True)
    with console.status("evaluating"):
        ev = evaluate_run(run_dir, dataset=args.dataset, max_frames=args.frames)
        if args.no_report:
            atomic_write_json(run_dir / "report" / "results.json", ev.results)
            index = None
        else:
            index = write_report(ev, run_dir)
    if args.json:
        print(json.dumps(json_summary(ev.results), indent=2, sort_keys=True))
        return 0
    t = Table(title=f"prt eval {run_dir}")
    for col in ("model", "split", "vis_rel_err", "psnr_diffuse", "psnr_glossy", "jitter"):
        t.add_column(col)
    for kind, splits in ev.results["models"].items():
        for split, m in splits.items():
            t.add_row(kind, split, f"{m['vis_rel_err']:.4f}", f"{m['psnr_diffuse']:.2f}", f"{m['psnr_glossy']:.2f}",
                      f"{m['jitter']:.4f}")
    console.print(t)
    if index is not None:
        console.print(f"report: {index}")
    return 0

"""``prt train CONFIG``: fit the linear, quadratic and MLP visibility models of a run."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

HELP = "Fit pose->visibility models (linear, quadratic, per-cluster MLP) on the baked dataset of runs/NAME."


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("config", help="run config (YAML), e.g. configs/builtin.yaml")
    parser.add_argument("--dataset", default=None, help="baked dataset to read (default: the run's own)")
    parser.add_argument("--run-dir", default=None, help="output run directory (default: runs/<name>)")
    parser.add_argument("--kinds", default=None, help="comma-separated subset of linear,quadratic,mlp")
    parser.add_argument("--device", default=None,
                        help="where the fit runs: auto (cuda when torch sees a GPU), cpu or cuda "
                             "(default: the config's train.device)")
    parser.add_argument("--json", action="store_true", help="print the metrics as JSON")


def run(args: argparse.Namespace) -> int:
    from prt_torch.commands import _validate as V
    from prt_torch.config import load_config
    from prt_torch.errors import PrtError, check
    from prt_torch.fit.config import KINDS
    from prt_torch.fit.device import DEVICES, resolve_device
    from prt_torch.fit.train import dataset_of, train_dataset
    from prt_torch.progress import make_console, progress_bar
    from prt_torch.rundir import RunDir

    kinds = V.names(args.kinds, "--kinds", KINDS, what="model kind") if args.kinds is not None else None
    if args.device is not None:
        check(args.device in DEVICES, f"--device: unknown device {args.device[:32]!r}: expected one of "
                                      f"{', '.join(DEVICES)}")
    if args.run_dir is not None:
        V.run_dir(args.run_dir, "--run-dir")
    if args.dataset is not None:
        V.input_path(args.dataset, "--dataset")
    cfg = load_config(args.config, run_dir=args.run_dir or None)
    tcfg = cfg.train
    if kinds:
        tcfg = tcfg.model_validate({**tcfg.model_dump(), "kinds": kinds,
                                    "default_kind": tcfg.default_kind if tcfg.default_kind in kinds else kinds[-1]})
    if args.device is not None:
        tcfg = tcfg.model_validate({**tcfg.model_dump(), "device": args.device})
    resolve_device(tcfg.device)  # cuda without a GPU: one line, before any work
    run = RunDir(cfg.out_dir)
    dataset = Path(args.dataset) if args.dataset else dataset_of(cfg)
    if not Path(dataset).exists():
        raise PrtError(f"dataset not found: {dataset} (run `prt bake` first, or pass --dataset)")
    console = make_console(stderr=True)
    with progress_bar(counted=False, spinner=True, console=console, transient=True) as progress:
        metrics = train_dataset(dataset, run, tcfg, progress)
    if args.json:
        print(json.dumps(metrics, indent=2, sort_keys=True))
    else:
        for kind, m in metrics["models"].items():
            errs = "  ".join(f"{s} {m[s]['vis_rel_err']:.4f}" for s in ("train", "heldout") if s in m)
            console.print(f"{kind:10s} fit {m['fit_s']:8.2f} s   vis_rel_err {errs}")
        console.print(f"wrote {run.model_path()}, {run.models_dir}/, {run.model_json}, {run.metrics_json}")
    return 0

"""``prt bench fit``: fit times of the three model kinds on one training set, side by side.

Seed 003 Table 1 reports 14 h 32 min (MLP) vs 12 min (linear), a 73x ratio. Here every kind is
fitted on the same reduced training data in one process (CV included, as ``prt train`` does), and
the ratio MLP / linear is printed. The data: ``--dataset`` (a baked dataset or a run directory holding
one, e.g. ``runs/builtin``) or, by default, a fresh small bake of the built-in character.

``--device cpu,cuda`` fits every kind on each device in turn (same reduced data, same process) and prints
each device's times and its speedup over the first; the top-level keys are the first device's.
"""

from __future__ import annotations

import argparse
import json
import resource
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

KINDS = ("linear", "quadratic", "mlp")
HELP = "Fit times of linear, quadratic and MLP models on the built-in training set, and MLP/linear."


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--dataset", default=None,
                        help="baked dataset or run directory (default: bake the built-in character small)")
    parser.add_argument("--config", default=None, help="run config whose train section to use (default: defaults)")
    parser.add_argument("--max-iter", type=int, default=None, help="override train.max_iter")
    parser.add_argument("--device", default=None,
                        help="comma-separated fit devices among auto,cpu,cuda, timed side by side "
                             "(default: the config's train.device)")
    parser.add_argument("--json", action="store_true", help="print a JSON object")


def _small_bake(tmp: Path) -> Path:
    from prt_torch.bake.runner import bake
    from prt_torch.config import config_from_dict

    cfg = config_from_dict({
        "name": "bench_fit", "run_dir": str(tmp),
        "character": {"source": "builtin", "density": 0.25, "fps": 10.0, "train_clips": ["stretch"],
                      "random_poses": 60, "heldout_clips": ["wave"], "seed": 0},
        "bake": {"order": 4, "n_rays": 128, "frames_per_task": 8, "seed": 0},
    })
    return Path(bake(cfg, workers=1, progress=False))


def _measured(fn: Callable[[], Any]) -> tuple[Any, dict[str, float]]:
    """Run ``fn``; its result and ``wall_s``, ``user_s``, ``sys_s``, ``page_faults`` (minor + major) of this process."""
    r0 = resource.getrusage(resource.RUSAGE_SELF)
    t0 = time.perf_counter()
    out = fn()
    wall = time.perf_counter() - t0
    r1 = resource.getrusage(resource.RUSAGE_SELF)
    return out, {"wall_s": wall, "user_s": r1.ru_utime - r0.ru_utime, "sys_s": r1.ru_stime - r0.ru_stime,
                 "page_faults": (r1.ru_minflt - r0.ru_minflt) + (r1.ru_majflt - r0.ru_majflt)}


def run(args: argparse.Namespace) -> int:
    import torch
    from threadpoolctl import threadpool_limits

    from prt_torch import limits
    from prt_torch.bake.store import open_dataset
    from prt_torch.commands import _validate as V
    from prt_torch.config import load_config
    from prt_torch.fit.config import TrainConfig
    from prt_torch.fit.device import DEVICES, fit_device, resolve_device
    from prt_torch.fit.inputs import load_skinning
    from prt_torch.fit.kinds import fit_mlp_kind, fit_ridge_kind, reduce_training
    from prt_torch.progress import make_console

    if args.max_iter is not None:
        limits.check_int(args.max_iter, "--max-iter", 1, limits.MAX_ITERATIONS)
    if args.dataset is not None:
        V.input_path(args.dataset, "--dataset")
    console = make_console(stderr=True)
    cfg = load_config(args.config).train if args.config else TrainConfig()
    if args.max_iter:
        cfg = cfg.model_copy(update={"max_iter": args.max_iter})
    asked = V.names(args.device, "--device", DEVICES, what="device") if args.device is not None else [cfg.device]
    devices = list(dict.fromkeys(resolve_device(d) for d in asked))  # cuda without a GPU: one line, before work
    with tempfile.TemporaryDirectory() as tmp:
        if args.dataset:
            dataset = Path(args.dataset)
        else:
            with console.status("baking the built-in character (small)"):
                dataset = _small_bake(Path(tmp) / "run")
        info = open_dataset(dataset)
        train = info.split("train")
        threads = torch.get_num_threads()
        torch.set_num_threads(max(cfg.threads, 1))
        try:
            with threadpool_limits(limits=max(cfg.threads, 1)):
                # the same reduction as prt train (per-cluster joint inputs when the config selects them)
                skinning = load_skinning(info) if cfg.input_selection == "joints" else None
                red, m = _measured(lambda: reduce_training(train, info.cluster, cfg, skinning))
                reduce_s = m["wall_s"]
                per_device: dict[str, tuple[dict[str, dict[str, float]], Any]] = {}
                for name in devices:
                    dev = fit_device(name)
                    usage = {"reduce": m}
                    for kind in ("linear", "quadratic"):
                        _, usage[kind] = _measured(lambda kind=kind, dev=dev: fit_ridge_kind(kind, red, cfg.alphas,
                                                                                             device=dev))
                    mlp, usage["mlp"] = _measured(lambda dev=dev: fit_mlp_kind(red, cfg, device=dev))
                    per_device[name] = (usage, mlp)
                usage, mlp = per_device[devices[0]]
                times = {k: u["wall_s"] for k, u in usage.items()}
                total = {f: sum(u[f] for u in usage.values()) for f in ("user_s", "sys_s", "page_faults")}
        finally:
            torch.set_num_threads(threads)
    by_device = {name: {**{f"{k}_s": u[k]["wall_s"] for k in KINDS}, "mlp_objective": r.choice.get("objective"),
                        "mlp_iterations": r.choice.get("iterations"),
                        f"speedup_vs_{devices[0]}": {k: times[k] / max(u[k]["wall_s"], 1e-9) for k in KINDS}}
                 for name, (u, r) in per_device.items()}
    out = {"device": devices[0], "devices": by_device,
           "linear_s": times["linear"], "quadratic_s": times["quadratic"], "mlp_s": times["mlp"],
           "mlp_over_linear": times["mlp"] / max(times["linear"], 1e-9),
           "quadratic_over_linear": times["quadratic"] / max(times["linear"], 1e-9),
           "reduce_s": reduce_s, "frames": int(red.x.shape[0]), "reduced_inputs": int(red.x.shape[1]),
           "mlp_inputs": int(red.inputs("mlp")[0].shape[1]), "input_selection": cfg.input_selection,
           **total,  # reduction + the three fits; per kind below
           **{f"{k}_{f}": usage[k][f] for k in KINDS for f in ("user_s", "sys_s", "page_faults")},
           "clusters": int(red.z.shape[1]), "output_width": int(red.z.shape[2]),
           "mlp_iterations": mlp.choice.get("iterations"), "cv_grid": {"alphas": len(cfg.alphas),
                                                                       "mlp_alphas": len(cfg.mlp_alphas),
                                                                       "neurons": cfg.neurons, "folds": cfg.folds},
           "seed003_table1_mlp_over_linear": 73.0}
    if args.json:
        print(json.dumps(out, indent=2))
    else:
        console.print(f"fit on {out['frames']} frames, {out['reduced_inputs']} inputs, {out['clusters']} clusters "
                      f"(reduction {reduce_s:.2f} s)")
        for k in ("linear", "quadratic", "mlp"):
            u = usage[k]
            console.print(f"  {k:10s} {times[k]:9.3f} s   x{times[k] / max(times['linear'], 1e-9):8.1f} linear   "
                          f"(user {u['user_s']:.2f} s, sys {u['sys_s']:.2f} s, {u['page_faults']} page faults)")
        console.print(f"MLP / linear = {out['mlp_over_linear']:.1f} (seed 003 Table 1: 73x) on {devices[0]}")
        for name in devices[1:]:
            d = by_device[name]
            ratios = "  ".join(f"{k} {d[f'{k}_s']:.3f} s (x{d[f'speedup_vs_{devices[0]}'][k]:.1f})" for k in KINDS)
            console.print(f"  on {name}: {ratios} vs {devices[0]}; MLP objective {d['mlp_objective']:.6g} "
                          f"vs {by_device[devices[0]]['mlp_objective']:.6g}")
    return 0

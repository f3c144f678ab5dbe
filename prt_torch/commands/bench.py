"""``prt bench NAME``: benchmark scripts that print ratios measured side by side in one run.

Each benchmark lives in ``prt_torch/commands/bench_<name>.py`` with the same interface as a
command module (``HELP``, ``add_arguments``, ``run``).
"""

from __future__ import annotations

import argparse
import importlib

HELP = "Benchmarks (bake, fit, play, shade): our path vs the raw limit or the naive way, in one run."

BENCHES = ("bake", "fit", "play", "shade")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    sub = parser.add_subparsers(dest="bench", metavar="NAME")
    sub.required = True
    for name in BENCHES:
        modname = f"prt_torch.commands.bench_{name}"
        try:
            mod = importlib.import_module(modname)
        except ModuleNotFoundError as exc:
            if exc.name != modname:
                raise
            continue
        p = sub.add_parser(name, help=getattr(mod, "HELP", ""), description=getattr(mod, "HELP", ""))
        mod.add_arguments(p)
        p.set_defaults(_bench_run=mod.run)


def run(args: argparse.Namespace) -> int:
    return int(args._bench_run(args) or 0)

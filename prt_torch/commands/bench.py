"""``prt bench NAME``: benchmark scripts that print ratios measured side by side in one run.

Each benchmark lives in ``prt_torch/commands/bench_<name>.py`` with the same interface as a
command module (``HELP``, ``add_arguments``, ``run``).
"""

from __future__ import annotations

import argparse

HELP = "Benchmarks (bake, fit, play, shade, heightfield): our path vs the raw limit or the naive way, in one run."

BENCHES = ("bake", "fit", "play", "shade", "heightfield", "scene", "sglight", "sg", "shexp", "cloth", "s001")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from prt_torch.cli import add_command_modules

    add_command_modules(parser, {name: f"prt_torch.commands.bench_{name}" for name in BENCHES}, "bench", "_bench_run")


def run(args: argparse.Namespace) -> int:
    return int(args._bench_run(args) or 0)

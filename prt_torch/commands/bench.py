"""``prt bench NAME``: benchmark scripts that print ratios measured side by side in one run.

Each benchmark is a module with the same interface as a command module (``HELP``, ``add_arguments``, ``run``):
the core stages' in ``prt_torch/commands/bench_<name>.py``, a method package's in ``prt_torch/<package>/bench.py``
(:data:`BENCHES`, the table ``prt bench`` offers).
"""

from __future__ import annotations

import argparse

HELP = "Benchmarks (bake, fit, play, shade, heightfield): our path vs the raw limit or the naive way, in one run."

#: ``prt bench NAME`` -> its module (one line per benchmark; a method package's bench lives in the package)
BENCHES: dict[str, str] = {
    "bake": "prt_torch.commands.bench_bake",
    "fit": "prt_torch.commands.bench_fit",
    "play": "prt_torch.commands.bench_play",
    "shade": "prt_torch.commands.bench_shade",
    "heightfield": "prt_torch.heightfield.bench",
    "scene": "prt_torch.commands.bench_scene",
    "web": "prt_torch.commands.bench_web",
    "sglight": "prt_torch.commands.bench_sglight",
    "sg": "prt_torch.vct.bench",
    "shexp": "prt_torch.shexp.bench",
    "cloth": "prt_torch.cloth.bench",
    "s001": "prt_torch.s001.bench",
    "rpo": "prt_torch.commands.bench_rpo",
}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from prt_torch.cli import add_command_modules

    add_command_modules(parser, BENCHES, "bench", "_bench_run")


def run(args: argparse.Namespace) -> int:
    return int(args._bench_run(args) or 0)

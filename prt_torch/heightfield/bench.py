"""``prt bench heightfield``: a thin alias of ``prt heightfield`` (the height-field generator vs Embree, side by
side in one run: ms per frame and their ratio, with the error and image PSNR that go with them)."""

from __future__ import annotations

import argparse

from prt_torch.heightfield import command as _hf

HELP = "Height-field visibility vs Embree: ms per frame and ratio (alias of `prt heightfield`)."


def add_arguments(parser: argparse.ArgumentParser) -> None:
    _hf.add_arguments(parser)


def run(args: argparse.Namespace) -> int:
    return _hf.run(args)

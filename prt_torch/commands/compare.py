"""``prt compare``: placeholder while it is being written (replaced in this change)."""

from __future__ import annotations

import argparse

HELP = "(being written)"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    pass


def run(args: argparse.Namespace) -> int:
    raise NotImplementedError

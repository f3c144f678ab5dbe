"""The ``prt`` command: one entry point, one module per sub-command.

Each sub-command lives in ``prt_torch/commands/<name>.py`` and defines

* ``HELP: str`` - one line shown in ``prt --help``;
* ``add_arguments(parser: argparse.ArgumentParser) -> None``;
* ``run(args: argparse.Namespace) -> int`` - the exit status.

Command modules keep heavy imports (torch, embreex, pyvista) inside ``run`` so that ``prt --help``
stays fast and ``prt play`` never imports torch. Errors of type :class:`prt_torch.PrtError` (and
missing files) are printed as one line, ``error: ...``, with exit status 2 and no traceback.
"""

from __future__ import annotations

import argparse
import importlib
import sys
from collections.abc import Sequence

#: sub-command name -> module path
COMMANDS: dict[str, str] = {
    "demo": "prt_torch.commands.demo",
    "light": "prt_torch.commands.light",
    "bake": "prt_torch.commands.bake",
    "train": "prt_torch.commands.train",
    "eval": "prt_torch.commands.eval",
    "export": "prt_torch.commands.export",
    "play": "prt_torch.commands.play",
    "compare": "prt_torch.commands.compare",
    "info": "prt_torch.commands.info",
    "bench": "prt_torch.commands.bench",
}


def add_command_modules(parser: argparse.ArgumentParser, modules: dict[str, str], dest: str, run_attr: str) -> None:
    """Add one required sub-parser per command module (``HELP``, ``add_arguments``, ``run``).

    The chosen module's ``run`` is stored on the namespace as ``run_attr``.
    """
    sub = parser.add_subparsers(dest=dest, metavar=dest.upper() if dest != "bench" else "NAME")
    sub.required = True
    for name, modname in modules.items():
        mod = importlib.import_module(modname)
        p = sub.add_parser(name, help=getattr(mod, "HELP", ""), description=getattr(mod, "HELP", ""))
        mod.add_arguments(p)
        p.set_defaults(**{run_attr: mod.run})


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="prt", description="prt_torch: learned PRT for animated characters.")
    add_command_modules(parser, COMMANDS, "command", "_run")
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    from prt_torch.errors import PrtError

    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args._run(args) or 0)
    except PrtError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except FileNotFoundError as exc:
        print(f"error: file not found: {exc.filename or exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("error: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())

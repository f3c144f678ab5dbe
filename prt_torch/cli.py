"""The ``prt`` command: one entry point, one module per sub-command.

Each sub-command lives in ``prt_torch/commands/<name>.py`` and defines

* ``HELP: str`` - one line shown in ``prt --help``;
* ``add_arguments(parser: argparse.ArgumentParser) -> None``;
* ``run(args: argparse.Namespace) -> int`` - the exit status.

Command modules keep heavy imports (torch, embreex, pyvista) inside ``run`` so that ``prt --help``
stays fast and ``prt play`` never imports torch. Errors of type :class:`prt_torch.PrtError` (and
missing files) are printed as one line, ``error: ...``, with exit status 2 and no traceback; warnings raised
while a command runs (:func:`prt_torch.errors.warn`) are printed as one line each, ``warning: ...``.
"""

from __future__ import annotations

import argparse
import importlib
import sys
import warnings
from collections.abc import Sequence
from typing import Any, NoReturn, TextIO

import prt_torch

#: sub-command name -> module path
COMMANDS: dict[str, str] = {
    "demo": "prt_torch.commands.demo",
    "light": "prt_torch.commands.light",
    "simulate": "prt_torch.cloth.command",
    "bake": "prt_torch.commands.bake",
    "train": "prt_torch.commands.train",
    "eval": "prt_torch.commands.eval",
    "export": "prt_torch.commands.export",
    "play": "prt_torch.commands.play",
    "compare": "prt_torch.commands.compare",
    "info": "prt_torch.commands.info",
    "init": "prt_torch.commands.init",
    "bench": "prt_torch.commands.bench",
    "heightfield": "prt_torch.heightfield.command",
    "web": "prt_torch.commands.web",
}


class PrtArgumentParser(argparse.ArgumentParser):
    """An :class:`argparse.ArgumentParser` whose argument errors are ONE line, ``error: prt CMD: ...``, exit 2.

    argparse prints a usage block before the message; the ``prt`` convention is one line per error
    (``--help`` is unchanged). Sub-parsers inherit the class (``add_subparsers`` uses the parent's type).
    """

    def error(self, message: str) -> NoReturn:  # type: ignore[override]
        """Print ``error: <prog>: <message>`` on one line to stderr and exit with status 2."""
        text = " ".join(str(message).split())
        self.exit(2, f"error: {self.prog}: {text}\n")


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
    """The ``prt`` parser: one sub-parser per :data:`COMMANDS` entry, one-line argument errors."""
    parser = PrtArgumentParser(prog="prt", description="prt_torch: learned PRT for animated characters.")
    parser.add_argument("--version", action="version", version=f"prt {prt_torch.__version__}")
    add_command_modules(parser, COMMANDS, "command", "_run")
    return parser


#: commands whose results must not depend on the machine (the bake's plan, the fits): they start with pinned BLAS
#: kernels (prt_torch.kernels, docs/DESIGN.md "Determinism")
PINNED_COMMANDS = ("bake", "train", "demo")


def main(argv: Sequence[str] | None = None) -> int:
    """Parse ``argv`` and run the command: its exit status (argument errors exit 2 from the parser)."""
    words = list(sys.argv[1:] if argv is None else argv)
    if words and words[0] in PINNED_COMMANDS:
        from prt_torch.kernels import pin_kernels

        pin_kernels()  # before the command modules load numpy / torch
    parser = build_parser()
    args = parser.parse_args(argv)
    with warnings.catch_warnings():
        warnings.showwarning = _show_warning
        return _run(args)


def _run(args: argparse.Namespace) -> int:
    """Run the chosen command; its errors as one ``error: ...`` line each (exit status 2)."""
    from prt_torch.errors import PrtError

    try:
        return int(args._run(args) or 0)
    except PrtError as exc:
        print(f"error: {_one_line(exc)}", file=sys.stderr)
        return 2
    except FileNotFoundError as exc:
        print(f"error: file not found: {_one_line(exc.filename or exc)}", file=sys.stderr)
        return 2
    except OSError as exc:  # a directory where a file was expected, permissions, a full disk, a refused connection
        where = f": {exc.filename}" if exc.filename else ""
        print(f"error: {_one_line(f'{exc.strerror or type(exc).__name__}{where}')}", file=sys.stderr)
        return 2
    except MemoryError:
        print("error: out of memory (a request over what this machine holds; see prt_torch/limits.py)",
              file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("error: interrupted", file=sys.stderr)
        return 130


def _show_warning(message: Warning | str, category: type[Warning], filename: str, lineno: int,
                  file: TextIO | None = None, line: str | None = None, **_: Any) -> None:
    """``warnings.showwarning`` of the CLI: ``warning: <message>`` on one line to stderr (no source line)."""
    print(f"warning: {_one_line(message)}", file=sys.stderr if file is None else file)


def _one_line(x: object) -> str:
    """``x`` as text on one line (newlines and other control characters escaped)."""
    return "".join(c if c.isprintable() else repr(c)[1:-1] for c in str(x))


if __name__ == "__main__":
    sys.exit(main())

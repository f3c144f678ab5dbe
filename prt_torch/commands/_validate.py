"""Argument checks shared by the command modules: run them at the start of ``run()``, before anything is written.

Every check raises a one-line :class:`~prt_torch.errors.PrtError` naming the option; sizes are bounded by
:mod:`prt_torch.limits`. Standard library only (no numpy), so ``prt --help`` stays fast.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

from prt_torch.errors import PrtError

if TYPE_CHECKING:
    from prt_torch.config import RunConfig


def _show(path: str | Path) -> str:
    """A path for a message: control characters escaped, at most 200 characters."""
    s = "".join(c if c.isprintable() else repr(c)[1:-1] for c in str(path))
    return s if len(s) <= 200 else s[:197] + "..."


def _exists(p: Path) -> bool:
    try:
        return p.exists()
    except (OSError, ValueError):  # a NUL in the path, a name too long
        raise PrtError(f"not a usable path: {_show(p)}") from None


def input_file(path: str | Path, option: str) -> Path:
    """An existing file (not a directory)."""
    p = Path(path)
    if not _exists(p):
        raise PrtError(f"{option}: file not found: {_show(p)}")
    if p.is_dir():
        raise PrtError(f"{option}: {_show(p)} is a directory, expected a file")
    return p


def input_dir(path: str | Path, option: str) -> Path:
    """An existing directory."""
    p = Path(path)
    if not _exists(p):
        raise PrtError(f"{option} not found: {_show(p)}")
    if not p.is_dir():
        raise PrtError(f"{option}: {_show(p)} is not a directory")
    return p


def input_path(path: str | Path, option: str) -> Path:
    """An existing file or directory (a dataset store is a directory)."""
    p = Path(path)
    if not _exists(p):
        raise PrtError(f"{option}: not found: {_show(p)}")
    return p


def output_file(path: str | Path, option: str) -> Path:
    """A file to write: not an existing directory, in an existing directory."""
    p = Path(path)
    if not str(path).strip():
        raise PrtError(f"{option}: empty path")
    if _exists(p) and p.is_dir():
        raise PrtError(f"{option}: {_show(p)} is a directory, expected a file path")
    parent = p.parent
    if not parent.is_dir():
        raise PrtError(f"{option}: directory {_show(parent)} does not exist (for {_show(p)})")
    return p


def output_dir(path: str | Path, option: str) -> Path:
    """A directory to write into: an existing directory, or a new one in an existing directory."""
    p = Path(path)
    if not str(path).strip():
        raise PrtError(f"{option}: empty path")
    if _exists(p):
        if not p.is_dir():
            raise PrtError(f"{option}: {_show(p)} exists and is not a directory")
        return p
    if not p.parent.is_dir():
        raise PrtError(f"{option}: directory {_show(p.parent)} does not exist (for {_show(p)})")
    return p


def run_dir(path: str | Path, option: str) -> Path:
    """A run directory to create or reuse: not an existing file, nor below one."""
    from prt_torch.config import check_run_dir

    return check_run_dir(path, option)


def run_config(config: str | Path, run_dir_option: str | None) -> RunConfig:
    """The config file ``config``, its run directory replaced by ``--run-dir`` when given (checked first)."""
    from prt_torch.config import load_config

    if run_dir_option is not None:
        run_dir(run_dir_option, "--run-dir")
    return load_config(config, run_dir=run_dir_option or None)


def names(text: str, option: str, allowed: tuple[str, ...] | list[str] | None = None, what: str = "name") -> list[str]:
    """``"a,b"`` -> ``["a", "b"]``: at least one name, no repeats, each in ``allowed`` when given (an unknown
    one is named as an unknown ``what``)."""
    out = [s.strip() for s in text.split(",") if s.strip()]
    if not out:
        raise PrtError(f"{option}: no name given in {_show(text)!r}")
    if len(set(out)) != len(out):
        raise PrtError(f"{option}: repeated name in {_show(text)!r}")
    if allowed is not None:
        bad = [n for n in out if n not in allowed]
        if bad:
            raise PrtError(f"{option}: unknown {what} {_show(bad[0])!r}: expected one of {', '.join(allowed)}")
    return out

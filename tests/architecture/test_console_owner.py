"""No module constructs a ``rich.console.Console`` but :mod:`prt_torch.progress` (its one owner, ``make_console``).

Every module of ``prt_torch``, ``train`` and ``export`` is parsed: importing ``Console`` from ``rich.console``
(under any alias), or calling ``rich.console.Console`` / ``console.Console`` through a module, is an offence
anywhere but ``prt_torch/progress.py``; so every console gets the same settings (no source locations in log
lines, a non-terminal width).
"""

from __future__ import annotations

import ast
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
OWNER = REPO / "prt_torch" / "progress.py"


def offences(source: str) -> list[tuple[int, str]]:
    """``(line, what)`` of every ``Console`` import from ``rich.console`` and every ``<module>.Console(...)``
    call whose module path ends in ``console`` (``rich.console.Console``, ``console.Console``)."""
    bad = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.ImportFrom) and node.module == "rich.console":
            bad += [(node.lineno, f"from rich.console import {a.name}") for a in node.names if a.name == "Console"]
        elif isinstance(node, ast.ImportFrom) and node.module == "rich":
            bad += [(node.lineno, "from rich import console") for a in node.names if a.name == "console"]
        elif (isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute) and node.func.attr == "Console"
              and ast.unparse(node.func.value).split(".")[-1] == "console"):
            bad.append((node.lineno, ast.unparse(node.func)))
    return bad


def test_the_check_finds_each_form() -> None:
    assert offences("def f():\n    from rich.console import Console as C\n    C()\n") == [
        (2, "from rich.console import Console")]
    assert offences("import rich.console\nrich.console.Console(stderr=True)\n") == [(2, "rich.console.Console")]
    assert offences("from rich import console\n") == [(1, "from rich import console")]
    assert offences("from rich.console import Group\nfrom rich.table import Table\nTable()\n") == []


def test_only_the_factory_builds_a_console() -> None:
    files = [p for d in ("prt_torch", "train", "export") for p in sorted((REPO / d).rglob("*.py"))]
    assert OWNER in files and len(files) > 50
    bad = [f"{p.relative_to(REPO)}:{line}: {what}" for p in files if p != OWNER
           for line, what in offences(p.read_text(encoding="utf-8"))]
    assert not bad, "build consoles with prt_torch.progress.make_console:\n" + "\n".join(bad)
    assert offences(OWNER.read_text(encoding="utf-8")), "the owner itself is expected to build one"

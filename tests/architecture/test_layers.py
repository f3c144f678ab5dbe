"""The packages import in one direction only (docs/DESIGN.md, "Layers").

Every ``import`` / ``from ... import`` of every module under ``prt_torch/`` (module level and inside
functions alike; only ``if TYPE_CHECKING:`` blocks are exempt, they never run) is checked against the
layer table below: a module may import its own package and anything of a LOWER rank, never a higher
rank. The one documented exception is :mod:`prt_torch.rundir`, the owner of the run directory: its
loading methods import their owners (``bake.store``, ``rig.character``, ``models.visibility``) lazily,
inside functions; at module level it is bottom-layer like everything else.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

PKG = Path(__file__).resolve().parents[2] / "prt_torch"

#: layer rank of each top-level unit of prt_torch (module or package); config schemas (``*.config``
#: modules) rank with ``config``: they are plain pydantic models every stage reads
RANKS: dict[str, int] = {
    "__init__": 0, "errors": 0, "shapes": 0, "io": 0, "runtime": 0, "rundir": 0, "config": 0, "limits": 0,
    "kernels": 0, "exact": 0,
    "conventions": 0, "progress": 0,
    "sh": 1,
    "light": 2, "brdf": 2,
    "shade": 3, "metrics": 3, "shexp": 3, "sg": 3,
    "rig": 4, "deform": 4,
    "bake": 5, "blockers": 5, "heightfield": 5, "vct": 5, "scene": 5, "cloth": 5,
    "reduce": 6, "models": 6,
    "fit": 7,
    "export": 8,
    "player": 9,
    "eval": 10, "compare": 10, "web": 10, "commands": 11, "cli": 11, "__main__": 12,
}

#: lazy (function-level) imports allowed to point up, for the run-directory owner only
LAZY_UP_OK = {"rundir": {"bake", "rig", "models"}}


def _unit(module: str) -> str:
    """``prt_torch.a.b`` -> its layer unit (``config`` for any ``prt_torch.<pkg>.config`` schema module)."""
    parts = module.split(".")
    if len(parts) >= 3 and parts[-1] == "config":
        return "config"
    return parts[1] if len(parts) > 1 else "__init__"


def _modules() -> list[tuple[str, Path]]:
    out = []
    for f in sorted(PKG.rglob("*.py")):
        rel = f.relative_to(PKG.parent).with_suffix("")
        parts = list(rel.parts)
        if parts[-1] == "__init__" and len(parts) > 1 and parts[0] == "prt_torch" and len(parts) == 2:
            parts = ["prt_torch", "__init__"]
        elif parts[-1] == "__init__":
            parts = parts[:-1]
        out.append((".".join(parts), f))
    return out


def _imports(tree: ast.AST, module: str) -> list[tuple[str, int, bool]]:
    """``(imported module, line, inside a function)`` for every prt_torch import outside TYPE_CHECKING."""
    found: list[tuple[str, int, bool]] = []
    pkg_parts = module.split(".")

    def visit(node: ast.AST, in_func: bool) -> None:
        for child in ast.iter_child_nodes(node):
            if isinstance(child, ast.If) and "TYPE_CHECKING" in ast.unparse(child.test):
                for c in child.orelse:
                    visit(c, in_func)
                continue
            func = in_func or isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda))
            if isinstance(child, ast.Import):
                found.extend((a.name, child.lineno, in_func) for a in child.names if a.name.startswith("prt_torch"))
            elif isinstance(child, ast.ImportFrom):
                if child.level:
                    base = ".".join(pkg_parts[: len(pkg_parts) - child.level + 1])
                    mod = f"{base}.{child.module}" if child.module else base
                else:
                    mod = child.module or ""
                if mod.startswith("prt_torch"):
                    names = [f"{mod}.{a.name}" if mod == "prt_torch" else mod for a in child.names]
                    found.extend((n, child.lineno, in_func) for n in names)
            visit(child, func)

    visit(tree, False)
    return found


def _violations() -> list[str]:
    bad = []
    for module, path in _modules():
        src = _unit(module)
        assert src in RANKS, f"{module}: not in the layer table of tests/architecture/test_layers.py"
        for target, line, lazy in _imports(ast.parse(path.read_text()), module):
            dst = _unit(target)
            if dst == src:
                continue
            assert dst in RANKS, f"{module} imports {target}: not in the layer table"
            if RANKS[dst] > RANKS[src] and not (lazy and dst in LAZY_UP_OK.get(src, set())):
                bad.append(f"{path.relative_to(PKG.parent)}:{line}: {src} (rank {RANKS[src]}) imports {target} "
                           f"({dst}, rank {RANKS[dst]})")
    return bad


def test_imports_follow_the_layers() -> None:
    bad = _violations()
    assert not bad, "imports against the data flow:\n" + "\n".join(bad)


def test_every_unit_has_a_rank() -> None:
    units = {_unit(m) for m, _ in _modules()}
    assert units <= set(RANKS), f"add these to the layer table: {sorted(units - set(RANKS))}"


@pytest.mark.parametrize("src,dst", [("fit", "eval"), ("export", "player"), ("sh", "shade"), ("bake", "fit"),
                                     ("rig", "bake"), ("models", "fit"), ("metrics", "eval")])
def test_checker_catches_an_upward_edge(src: str, dst: str) -> None:
    """The checker itself sees the edges this layering forbids (a planted module importing upward, lazily),
    and ignores ``TYPE_CHECKING`` imports."""
    assert RANKS[dst] > RANKS[src]
    tree = ast.parse(f"def f():\n    from prt_torch.{dst} import x\n")
    edges = _imports(tree, f"prt_torch.{src}.planted")
    assert edges and _unit(edges[0][0]) == dst and RANKS[_unit(edges[0][0])] > RANKS[src]
    tree = ast.parse(f"from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from prt_torch.{dst} import x\n")
    assert _imports(tree, f"prt_torch.{src}.planted") == []

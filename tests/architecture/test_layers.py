"""The packages import in one direction only (docs/DESIGN.md, "Layers").

Every ``import`` / ``from ... import`` of every module under ``prt_torch/`` (module level and inside
functions alike; only ``if TYPE_CHECKING:`` blocks are exempt, they never run) is checked against the
layer table below: a module may import its own package and anything of a LOWER rank, never a higher
rank. The one documented exception is :mod:`prt_torch.rundir`, the owner of the run directory: its
loading methods import their owners (``bake.store``, ``rig.character``, ``models.visibility``) lazily,
inside functions; at module level it is bottom-layer like everything else.

The method packages (:data:`prt_torch.plugins.METHOD_PACKAGES`) rank above the core: a core module that imports
one fails with "go through a stage table (prt_torch.plugins)". A method package's CLI hook modules (the ones
``cli.COMMANDS`` and ``commands.bench.BENCHES`` name, :data:`CLI_HOOKS`) are command modules and rank with
``commands``. A method package never imports another method package (same rank is not enough), and every stage
table lists every method package and names only that package's modules (stated above
:data:`EXPECTED_TABLES`).

The same parsed imports also forbid import cycles among prt_torch modules (rundir's lazy loaders are left out of
the graph: a cycle only they close passes), ``_private`` names taken from another module, and dead code
(top-level definitions nothing references); the rules are stated above :func:`test_no_import_cycles`.
"""

from __future__ import annotations

import ast
import importlib
from collections.abc import Callable
from pathlib import Path

import pytest

from prt_torch.cli import COMMANDS
from prt_torch.commands.bench import BENCHES
from prt_torch.plugins import METHOD_PACKAGES

PKG = Path(__file__).resolve().parents[2] / "prt_torch"

#: layer rank of each top-level unit of prt_torch (module or package); config schemas (``*.config``
#: modules) rank with ``config``: they are plain pydantic models every stage reads
RANKS: dict[str, int] = {
    "__init__": 0, "errors": 0, "shapes": 0, "io": 0, "runtime": 0, "rundir": 0, "config": 0, "limits": 0,
    "kernels": 0, "exact": 0, "plugins": 0, "lazy": 0,
    "conventions": 0, "progress": 0,
    "sh": 1,
    "light": 2, "brdf": 2,
    "shade": 3, "metrics": 3, "sg": 3,
    "rig": 4, "deform": 4,
    "bake": 5, "blockers": 5, "scene": 5,
    "reduce": 6, "models": 6,
    "fit": 7,
    "export": 8,
    "player": 9,
    "scoring": 9.5,  # the shipping-path scoring kit: uses player, used by eval, compare and web
    "eval": 10, "compare": 10,
    **{pkg: 11 for pkg in METHOD_PACKAGES},  # one package per method (prt_torch.plugins); CLI hooks: CLI_HOOKS
    "web": 12, "commands": 12, "cli": 12, "__main__": 13,
}

#: lazy (function-level) imports allowed to point up, for the run-directory owner only
LAZY_UP_OK = {"rundir": {"bake", "rig", "models"}}

#: a method package's CLI hook modules, the ones :data:`prt_torch.cli.COMMANDS` and
#: :data:`prt_torch.commands.bench.BENCHES` name (``<pkg>/command.py``, ``<pkg>/bench.py``): command modules that
#: live with their method, so they rank with ``commands`` (they share its argument checks, ``commands._validate``)
CLI_HOOKS = frozenset(m for m in (*COMMANDS.values(), *BENCHES.values()) if m.split(".")[1] in METHOD_PACKAGES)


def _unit(module: str) -> str:
    """``prt_torch.a.b`` -> its layer unit (``config`` for any ``prt_torch.<pkg>.config`` schema module,
    ``commands`` for a method package's CLI hook module, :data:`CLI_HOOKS`)."""
    parts = module.split(".")
    if len(parts) >= 3 and parts[-1] == "config":
        return "config"
    if module in CLI_HOOKS:
        return "commands"
    return parts[1] if len(parts) > 1 else "__init__"


def _package(module: str) -> str | None:
    """The method package a module belongs to (its CLI hooks included), or ``None`` for a core module."""
    parts = module.split(".")
    return parts[1] if len(parts) > 2 and parts[1] in METHOD_PACKAGES else None


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
    for node, in_func in _import_nodes(tree):
        if isinstance(node, ast.Import):
            found.extend((a.name, node.lineno, in_func) for a in node.names if a.name.startswith("prt_torch"))
            continue
        if node.level:
            base = ".".join(pkg_parts[: len(pkg_parts) - node.level + 1])
            mod = f"{base}.{node.module}" if node.module else base
        else:
            mod = node.module or ""
        if mod.startswith("prt_torch"):
            names = [f"{mod}.{a.name}" if mod == "prt_torch" else mod for a in node.names]
            found.extend((n, node.lineno, in_func) for n in names)
    return found


def _violations(sources: dict[str, str]) -> list[str]:
    """``module:line: ...`` for every import of ``sources`` (``{module: source}``) against the layer table; a core
    module importing a method package says to go through a stage table."""
    bad = []
    for module, text in sources.items():
        src = _unit(module)
        assert src in RANKS, f"{module}: not in the layer table of tests/architecture/test_layers.py"
        for target, line, lazy in _imports(ast.parse(text), module):
            dst = _unit(target)
            if dst == src:
                continue
            assert dst in RANKS, f"{module} imports {target}: not in the layer table"
            if RANKS[dst] > RANKS[src] and not (lazy and dst in LAZY_UP_OK.get(src, set())):
                if dst in METHOD_PACKAGES and src not in METHOD_PACKAGES:
                    bad.append(f"{module}:{line}: core module {module} imports method package {dst} ({target}): go "
                               f"through a stage table (prt_torch.plugins)")
                else:
                    bad.append(f"{module}:{line}: {src} (rank {RANKS[src]}) imports {target} ({dst}, rank "
                               f"{RANKS[dst]})")
    return bad


def _cross_method_imports(sources: dict[str, str]) -> list[str]:
    """``module:line: ...`` for every import from one method package into ANOTHER (CLI hooks included): a method
    package imports only core layers."""
    bad = []
    for module, text in sources.items():
        own = _package(module)
        if own is None:
            continue
        for target, line, _lazy in _imports(ast.parse(text), module):
            other = target.split(".")[1] if target.count(".") else None
            if other in METHOD_PACKAGES and other != own:
                bad.append(f"{module}:{line}: method package {own} imports method package {other} ({target}): a "
                           f"method package imports only core layers")
    return bad


def test_imports_follow_the_layers() -> None:
    bad = _violations(_sources())
    assert not bad, "imports against the data flow:\n" + "\n".join(bad)


def test_method_packages_import_only_core_layers() -> None:
    bad = _cross_method_imports(_sources())
    assert not bad, "imports between method packages:\n" + "\n".join(bad)


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


# -- no import cycles, no private names across modules, no dead code ---------------------------------------------
#
# Three more rules on the same parsed sources (module-level and function-level imports alike, ``if TYPE_CHECKING:``
# blocks exempt as above):
#
# * no import cycle among prt_torch modules (``from pkg import sub`` is an edge to the submodule ``pkg.sub``). The one
#   exemption: the lazy loaders of :mod:`prt_torch.rundir` (``LAZY_UP_OK``, function-level imports of ``bake``,
#   ``rig``, ``models``) are left out of the graph, so a cycle that only they close passes; every other edge counts;
# * no ``_private`` name imported from another module (``from prt_torch.x import _y``), nor read as an attribute of
#   an imported prt_torch module (``import prt_torch.x as m`` / ``from prt_torch import x``, then ``m._y``); a
#   private name is its module's own: make it public in its owner, or move it;
# * no dead code: every top-level public function or class of prt_torch is referenced by name (a name, an
#   attribute, an imported name, or a string naming it, as ``monkeypatch.setattr`` and ``getattr`` do) somewhere in
#   prt_torch/, train/, export/, tests/ or scripts/ outside its own definition. Exempt: the command-module hooks
#   (:data:`ENTRY_POINTS`), names listed in their module's ``__all__``, and decorated definitions (a decorator such
#   as the compare methods' ``@register`` is what uses them).

ROOT = PKG.parent
#: where a public prt_torch name may be used from
USERS = ("prt_torch", "train", "export", "tests", "scripts")
#: names called by the CLI machinery, never by name (``prt_torch.cli.add_command_modules``, ``python -m``)
ENTRY_POINTS = frozenset({"run", "add_arguments", "main"})


def _sources() -> dict[str, str]:
    """``{module name: source}`` of every prt_torch module."""
    return {m: p.read_text() for m, p in _modules()}


def _import_nodes(tree: ast.AST) -> list[tuple[ast.Import | ast.ImportFrom, bool]]:
    """Every import statement outside ``if TYPE_CHECKING:``, with whether it runs inside a function."""
    found: list[tuple[ast.Import | ast.ImportFrom, bool]] = []

    def visit(node: ast.AST, in_func: bool) -> None:
        for child in ast.iter_child_nodes(node):
            if isinstance(child, ast.If) and "TYPE_CHECKING" in ast.unparse(child.test):
                for c in child.orelse:
                    visit(c, in_func)
                continue
            if isinstance(child, (ast.Import, ast.ImportFrom)):
                found.append((child, in_func))
            visit(child, in_func or isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda)))

    visit(tree, False)
    return found


def _from_module(node: ast.ImportFrom, module: str, is_pkg: bool) -> str:
    """The absolute module of a ``from ... import`` (relative levels resolved against ``module``)."""
    if not node.level:
        return node.module or ""
    parts = module.split(".") + ([""] if is_pkg else [])
    base = ".".join(parts[: len(parts) - node.level])
    return f"{base}.{node.module}" if node.module else base


def _is_package(module: str, sources: dict[str, str]) -> bool:
    return any(m.startswith(module + ".") for m in sources)


def _edges(sources: dict[str, str]) -> dict[str, dict[str, bool]]:
    """``{module: {imported prt_torch module: only lazily}}``, the rundir loaders' exempt edges left out."""
    graph: dict[str, dict[str, bool]] = {m: {} for m in sources}

    def owner(name: str) -> str | None:
        while name and name not in sources:
            name = name.rpartition(".")[0]
        return name or None

    for module, text in sources.items():
        for node, lazy in _import_nodes(ast.parse(text)):
            if isinstance(node, ast.Import):
                targets = [a.name for a in node.names]
            else:
                mod = _from_module(node, module, _is_package(module, sources))
                targets = [f"{mod}.{a.name}" if f"{mod}.{a.name}" in sources else mod for a in node.names]
            for t in targets:
                dst = owner(t) if t.startswith("prt_torch") else None
                if dst is None or dst == module:
                    continue
                if lazy and _unit(dst) in LAZY_UP_OK.get(_unit(module), set()):
                    continue  # the run directory's documented lazy loaders
                graph[module][dst] = graph[module].get(dst, True) and lazy
    return graph


def _cycles(sources: dict[str, str]) -> list[list[str]]:
    """The import cycles of ``sources``: every strongly connected component of more than one module (Tarjan)."""
    graph = _edges(sources)
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    out: list[list[str]] = []

    def connect(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in graph[v]:
            if w not in index:
                connect(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    for v in sorted(graph):
        if v not in index:
            connect(v)
    return sorted(out)


def _private(name: str) -> bool:
    return name.startswith("_") and not (name.startswith("__") and name.endswith("__"))


def _private_imports(sources: dict[str, str]) -> list[str]:
    """``module:line: name`` of every private name a module takes from another prt_torch module."""
    bad = []
    for module, text in sources.items():
        tree = ast.parse(text)
        aliases: set[str] = set()  # local names bound to another prt_torch module
        for node, _lazy in _import_nodes(tree):
            if isinstance(node, ast.Import):
                aliases.update(a.asname for a in node.names if a.asname and a.name.startswith("prt_torch"))
                continue
            mod = _from_module(node, module, _is_package(module, sources))
            if not mod.startswith("prt_torch") or mod == module:
                continue
            for a in node.names:
                if f"{mod}.{a.name}" in sources:
                    aliases.add(a.asname or a.name)
                elif _private(a.name):
                    bad.append(f"{module}:{node.lineno}: from {mod} import {a.name}")
        for node in ast.walk(tree):
            if (isinstance(node, ast.Attribute) and _private(node.attr) and isinstance(node.value, ast.Name)
                    and node.value.id in aliases):
                bad.append(f"{module}:{node.lineno}: {node.value.id}.{node.attr}")
    return bad


def _referenced(texts: list[str]) -> set[str]:
    """Every name the sources use: names, attributes, imported names, and identifiers inside string constants."""
    used: set[str] = set()
    for text in texts:
        for node in ast.walk(ast.parse(text)):
            if isinstance(node, ast.Name):
                used.add(node.id)
            elif isinstance(node, ast.Attribute):
                used.add(node.attr)
            elif isinstance(node, ast.alias):
                used.add(node.name.rpartition(".")[2])
            elif isinstance(node, ast.Constant) and isinstance(node.value, str) and len(node.value) < 200:
                words = [w.rpartition(":")[2] if ":" in w else w for w in node.value.split()]  # "module:attr" refs
                used.update(w.rpartition(".")[2] for w in words if w.replace(".", "_").isidentifier())
    return used


def _dead(sources: dict[str, str], users: list[str]) -> list[str]:
    """``module.name`` of every top-level public function or class of ``sources`` that no source of ``sources``
    or ``users`` references by name (exempt: :data:`ENTRY_POINTS`, ``__all__`` entries, decorated definitions), and
    of every private one its own module does not use (dunders such as a module ``__getattr__`` are hooks)."""
    used = _referenced([*sources.values(), *users])
    bad = []
    for module, text in sources.items():
        tree = ast.parse(text)
        exported: set[str] = set()
        for node in tree.body:
            if isinstance(node, ast.Assign) and any(getattr(t, "id", None) == "__all__" for t in node.targets):
                exported.update(e.value for e in ast.walk(node.value) if isinstance(e, ast.Constant))
        own: set[str] | None = None
        for node in tree.body:
            defs = (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)
            if not isinstance(node, defs) or node.name.startswith("__"):
                continue
            if node.name.startswith("_"):  # private: only its own module may use it
                own = _referenced([text]) if own is None else own
                if node.name not in own and not node.decorator_list:
                    bad.append(f"{module}.{node.name}")
                continue
            if node.name in ENTRY_POINTS or node.name in exported or node.decorator_list or node.name in used:
                continue
            bad.append(f"{module}.{node.name}")
    return bad


def _user_sources() -> list[str]:
    return [f.read_text() for d in USERS[1:] for f in sorted((ROOT / d).rglob("*.py")) if "__pycache__" not in f.parts]


def test_no_import_cycles() -> None:
    cycles = _cycles(_sources())
    assert not cycles, "import cycles (move the shared piece down into its owner):\n" + "\n".join(
        " <-> ".join(c) for c in cycles)


def test_no_private_names_across_modules() -> None:
    bad = _private_imports(_sources())
    assert not bad, "private names used outside their module (make them public in the owner):\n" + "\n".join(bad)


def test_no_dead_code() -> None:
    bad = _dead(_sources(), _user_sources())
    assert not bad, "top-level public names nothing references (remove them):\n" + "\n".join(bad)


def test_checker_catches_a_cycle() -> None:
    """A planted two-module cycle closed by a function-level import is caught, through ``from pkg import sub``
    too; a ``TYPE_CHECKING`` import does not close one, nor do the run directory's lazy loaders alone."""
    two = {"prt_torch.a": "from prt_torch.b import f\n", "prt_torch.b": "def f():\n    from prt_torch.a import g\n"}
    assert _cycles(two) == [["prt_torch.a", "prt_torch.b"]]
    pkg = {"prt_torch.p": "from prt_torch.p import sub\nX = 1\n", "prt_torch.p.sub": "from prt_torch.p import X\n"}
    assert _cycles(pkg) == [["prt_torch.p", "prt_torch.p.sub"]]
    typed = {"prt_torch.a": "from prt_torch.b import f\n",
             "prt_torch.b": "from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from prt_torch.a import g\n"}
    assert _cycles(typed) == []
    lazy = {"prt_torch.rundir": "def dataset():\n    from prt_torch.bake.store import open_dataset\n",
            "prt_torch.bake.store": "from prt_torch.rundir import RunDir\n"}
    assert _cycles(lazy) == []
    lazy["prt_torch.rundir"] = "from prt_torch.bake.store import open_dataset\n"  # at module level: not exempt
    assert _cycles(lazy) == [["prt_torch.bake.store", "prt_torch.rundir"]]


def test_checker_catches_a_private_import() -> None:
    """``from prt_torch.x import _y`` (also lazily and relatively) and ``x._y`` on an imported module are caught;
    a module's own private names, dunders and public names are not."""
    src = {"prt_torch.x": "_y = 1\nz = 2\n",
           "prt_torch.a": "def f():\n    from prt_torch.x import _y\n",
           "prt_torch.p": "", "prt_torch.p.q": "_r = 1\n", "prt_torch.p.s": "from .q import _r\n",
           "prt_torch.b": "from prt_torch import x\nv = x._y\n",
           "prt_torch.c": "import prt_torch.x as m\nv = m._y\n",
           "prt_torch.ok": "from prt_torch.x import z\nfrom prt_torch import x\nv = x.__name__\n_w = 1\nu = _w\n"}
    bad = _private_imports(src)
    assert [b.split(":")[0] for b in bad] == ["prt_torch.a", "prt_torch.p.s", "prt_torch.b", "prt_torch.c"], bad


def test_checker_catches_dead_code() -> None:
    """An unreferenced public function or class is caught, and a private one its module does not use; one
    referenced from a user source (a test, a string naming it), an entry point, an ``__all__`` entry, a decorated
    definition, a private one its module uses and a dunder hook are not."""
    src = {"prt_torch.m": ("def dead():\n    pass\nclass Dead:\n    pass\ndef used():\n    pass\ndef patched():\n"
                           "    pass\ndef run(args):\n    pass\n__all__ = ['exported']\ndef exported():\n    pass\n"
                           "@register\nclass Method:\n    pass\ndef _private():\n    pass\ndef _helper():\n    pass\n"
                           "x = _helper()\ndef __getattr__(name):\n    pass\n")}
    users = ["from prt_torch.m import used\n", "monkeypatch.setattr('prt_torch.m.patched', None)\n"]
    assert _dead(src, users) == ["prt_torch.m.dead", "prt_torch.m.Dead", "prt_torch.m._private"]


# -- the method packages and the stage tables ----------------------------------------------------------------------
#
# docs/DESIGN.md, "Layers": the core stages import no method package (the layer check above says so: a core module's
# import of one fails with "go through a stage table"); a method package imports only core layers, never another
# method package (same rank is not enough: :func:`test_method_packages_import_only_core_layers`); and each stage
# finds the methods through a stage table (:mod:`prt_torch.plugins`): every module-level ``NAME: StageTable = {...}``
# of prt_torch lists EVERY method package, and each of its ``"module:attr"`` references names a module of THAT
# package and an attribute the module has.

#: every stage table of prt_torch, ``module:NAME`` (a new table is added here, so that none goes unnoticed)
EXPECTED_TABLES = frozenset({
    "prt_torch.bake.deformable:SUBJECTS",
    "prt_torch.bake.extras:BAKE_EXTRAS",
    "prt_torch.fit.stages:FIT_STAGES",
    "prt_torch.export.shippers:SHIPPERS",
    "prt_torch.player.renderers:RENDERERS",
    "prt_torch.player.sources:VISIBILITY_SOURCES",
    "prt_torch.compare.methods:COMPARE_METHODS",
})


def _stage_tables(sources: dict[str, str]) -> dict[str, ast.AnnAssign]:
    """``{"module:NAME": node}`` of every module-level ``NAME: StageTable = ...`` of ``sources``."""
    found = {}
    for module, text in sources.items():
        for node in ast.parse(text).body:
            if (isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name)
                    and ast.unparse(node.annotation) == "StageTable"):
                found[f"{module}:{node.target.id}"] = node
    return found


def _defines(text: str, name: str) -> bool:
    """Whether a module source binds ``name`` at module level (a def, class, assignment or import)."""
    for node in ast.parse(text).body:
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)) and node.name == name:
            return True
        targets = node.targets if isinstance(node, ast.Assign) else [node.target] if isinstance(
            node, ast.AnnAssign) else []
        if any(isinstance(t, ast.Name) and t.id == name for t in targets):
            return True
        if isinstance(node, (ast.Import, ast.ImportFrom)) and any(
                (a.asname or a.name.split(".")[0]) == name for a in node.names):
            return True
    return False


def _table_problems(sources: dict[str, str], packages: tuple[str, ...], has_attr: Callable[[str, str], bool]
                    ) -> list[str]:
    """``table: problem`` for every stage table of ``sources`` that does not list exactly ``packages``, or whose
    reference is not ``"prt_torch.<that package>.<module>:<attr>"`` with the module in ``sources`` and
    ``has_attr(module, attr)``."""
    bad = []
    for name, node in _stage_tables(sources).items():
        if node.value is None:
            bad.append(f"{name}: no value")
            continue
        try:
            table = ast.literal_eval(node.value)
        except ValueError:
            bad.append(f"{name}: not a literal dict of string tuples")
            continue
        if not isinstance(table, dict):
            bad.append(f"{name}: not a dict")
            continue
        if set(table) != set(packages):
            missing, extra = sorted(set(packages) - set(table)), sorted(set(table) - set(packages))
            bad.append(f"{name}: must list every method package (prt_torch.plugins.METHOD_PACKAGES): missing "
                       f"{missing}, not method packages {extra}")
        for package, refs in table.items():
            if not isinstance(refs, tuple):
                bad.append(f"{name}[{package!r}]: a tuple of references, () where the package has no hook")
                continue
            for ref in refs:
                module, _, attr = str(ref).partition(":")
                if not module.startswith(f"prt_torch.{package}.") or not attr:
                    bad.append(f"{name}[{package!r}]: {ref!r} is not 'prt_torch.{package}.<module>:<attr>' (a "
                               f"table names only its package's own modules)")
                elif module not in sources:
                    bad.append(f"{name}[{package!r}]: {ref!r}: no module {module}")
                elif not has_attr(module, attr):
                    bad.append(f"{name}[{package!r}]: {ref!r}: {module} has no {attr!r}")
    return bad


def test_every_stage_table_lists_every_method_package() -> None:
    sources = _sources()
    assert set(_stage_tables(sources)) == EXPECTED_TABLES, (
        "the stage tables changed: update EXPECTED_TABLES", sorted(set(_stage_tables(sources)) ^ EXPECTED_TABLES))

    def has_attr(module: str, attr: str) -> bool:  # bound in the source, else (a name made at run time) imported
        return _defines(sources[module], attr) or hasattr(importlib.import_module(module), attr)

    bad = _table_problems(sources, METHOD_PACKAGES, has_attr)
    assert not bad, "stage tables:\n" + "\n".join(bad)


def test_checker_catches_a_core_module_importing_a_method_package() -> None:
    """A planted core module importing a method package (lazily too) fails with the stage-table message; the
    method package importing the core and a command module importing the method do not."""
    src = {"prt_torch.fit.planted": "def f():\n    from prt_torch.s001.fit import fit_s001\n",
           "prt_torch.s001.fit": "from prt_torch.fit.kinds import KINDS\n",
           "prt_torch.commands.planted": "from prt_torch.s001 import fit\n"}
    bad = _violations(src)
    assert len(bad) == 1 and bad[0].startswith("prt_torch.fit.planted:2: core module prt_torch.fit.planted imports "
                                               "method package s001"), bad
    assert bad[0].endswith("go through a stage table (prt_torch.plugins)")


def test_checker_catches_a_method_package_importing_another() -> None:
    """A planted method package module importing another method package (lazily too, a CLI hook too) fails; its
    own package and the core do not."""
    hook = sorted(CLI_HOOKS)[0]
    src = {"prt_torch.cloth.planted": "from prt_torch.cloth.cache import VertexCache\nfrom prt_torch.player import x\n"
                                      "def f():\n    from prt_torch.local.soa import LocalOffsetsSoA\n",
           hook: "import prt_torch.s001.posespace\n" if not hook.startswith("prt_torch.s001.") else
                 "import prt_torch.vct.play\n"}
    bad = _cross_method_imports(src)
    assert [b.split(":")[0] for b in bad] == ["prt_torch.cloth.planted", hook], bad
    assert "method package cloth imports method package local" in bad[0]


def test_checker_catches_a_bad_stage_table() -> None:
    """A planted table missing a package, one naming a module of another package, one naming no module, an attribute
    its module lacks, and a non-tuple entry each fail; a complete table of existing hooks passes."""
    packages = ("a", "b")
    hooks = {"prt_torch.a.hook": "def f():\n    pass\n", "prt_torch.b.hook": "G = 1\n"}

    def table(body: str) -> dict[str, str]:
        return {**hooks, "prt_torch.stage": f"from prt_torch.plugins import StageTable\nT: StageTable = {body}\n"}

    def has(module: str, attr: str) -> bool:
        return _defines(hooks[module], attr)

    assert _table_problems(table('{"a": ("prt_torch.a.hook:f",), "b": ()}'), packages, has) == []
    cases = {
        '{"a": ("prt_torch.a.hook:f",)}': "must list every method package",
        '{"a": ("prt_torch.b.hook:G",), "b": ()}': "a table names only its package's own modules",
        '{"a": ("prt_torch.a.gone:f",), "b": ()}': "no module prt_torch.a.gone",
        '{"a": ("prt_torch.a.hook:g",), "b": ()}': "prt_torch.a.hook has no 'g'",
        '{"a": "prt_torch.a.hook:f", "b": ()}': "a tuple of references",
    }
    for body, message in cases.items():
        bad = _table_problems(table(body), packages, has)
        assert len(bad) == 1 and bad[0].startswith("prt_torch.stage:T") and message in bad[0], (body, bad)

"""Packaging: the dependency sets of ``pyproject.toml`` against what each entry point imports (installs nothing).

The base install (``pip install prt-torch``) is what ``prt play`` (and ``prt info``, ``prt light``,
``prt --help``) needs, and never torch; the extras ``bake``, ``train`` and ``export`` add what those
commands need; ``all`` is every extra; ``dev`` the test tools.

The check is static. From an entry point's command modules the walk follows every ``prt_torch.*``
import (``import a.b``, ``from a.b import c`` where ``c`` may be a submodule, relative imports, and
imports inside functions; the parent packages of every imported module too, since importing a
submodule runs them), skipping ``if TYPE_CHECKING:`` blocks. Every top-level module outside the
project and the standard library that the walk meets must belong to a distribution declared for
that entry point. Imports inside functions that an entry point reaches but never runs (torch for
torch-tensor inputs, scikit-learn for bake-time clustering, model loading in :class:`RunDir`, ...)
are listed in :data:`UNUSED_LAZY` with the reason; each listed one must still exist and be inside a
function, so the list cannot go stale or hide a module-level import.
"""

from __future__ import annotations

import ast
import importlib.metadata as md
import inspect
import json
import re
import subprocess
import sys
from dataclasses import dataclass
from functools import cache
from pathlib import Path

import pytest
from packaging.requirements import Requirement

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - python 3.10
    import tomli as tomllib

REPO = Path(__file__).resolve().parents[1]
PROJECT = "prt-torch"
PACKAGES = ("prt_torch", "train", "export")  # the installed top-level packages
LOCAL = (*PACKAGES, "tests")  # top-level modules of this repository

#: entry point -> (extras added to the base install, root modules of the walk)
ENTRY_POINTS: dict[str, tuple[tuple[str, ...], tuple[str, ...]]] = {
    "play": ((), ("prt_torch.commands.play", "prt_torch.commands.info", "prt_torch.commands.light")),
    "bake": (("bake",), ("prt_torch.commands.bake",)),
    "train": (("train",), ("prt_torch.commands.train", "prt_torch.commands.eval", "train.__main__")),
    "export": (("export",), ("prt_torch.commands.export", "export.__main__")),
    "sg": (("sg",), ("prt_torch.sg.lighting", "prt_torch.sg.brdf_fit", "prt_torch.sg.algebra")),
}

_TORCH_TENSORS = "only for torch-tensor input (numpy input never imports torch)"
_MEAN_SHIFT = "cluster_vertices (mean shift) runs at bake time; later stages read the stored clusters"
_RPO_BUILD = "factor_brdf/build_rpo build RPOs (prt export); the player only loads them"
_LOAD_MODEL = "RunDir.load_model (torch models) is for train/eval/export"

_DATASET = "RunDir.dataset (the zarr store) is for train/eval/export"
_MATERIAL_RPO = ("the character material's Cook-Torrance RPO is built once per run (`prt play --brdf material`, "
                 "`prt web`) and cached; without scikit-learn (player-only install) that is a one-line error")
_SG_LIGHT = "`prt light --sg` needs the sg extra (healpy, torch) and says so in one line without it"
_SG_SPLIT = ("`prt light FILE --peaks` (a map's light split: seed 004's peak detection) needs the sg extra and says so "
             "in one line without it; the procedural sky's split (`prt light sky --peaks`) is numpy only")

_EXACT_PEAKS = ("exact peak visibility (`--peak-visibility exact`, compare's oracle) traces Embree rays: the bake "
                "extra (embreex); the learned and sphere kinds need none of it")

#: entry point -> {"module: top" (a lazy import) or "module -> imported module" (a lazy edge): reason}
UNUSED_LAZY: dict[str, dict[str, str]] = {
    "play": {
        "prt_torch.sh.basis: torch": _TORCH_TENSORS,
        "prt_torch.sh.product: torch": _TORCH_TENSORS,
        "prt_torch.sh.rotation: torch": _TORCH_TENSORS,
        "prt_torch.sh.zonal: torch": _TORCH_TENSORS,
        "prt_torch.blockers.spheres: sklearn": "sphere blockers are fitted (k-means) by prt export; the scene player "
                                               "only loads and poses them",
        "prt_torch.blockers.capsules: sklearn": "learned capsules are fitted (k-means splits) by prt train; the player "
                                                "only loads and poses them",
        "prt_torch.blockers.cones: torch": _TORCH_TENSORS,
        "prt_torch.blockers.capsule_cones: torch": _TORCH_TENSORS,
        "prt_torch.player.peaks -> prt_torch.bake.embree": _EXACT_PEAKS,
        "prt_torch.player.player -> prt_torch.bake.embree": _EXACT_PEAKS,
        "prt_torch.player.scene -> prt_torch.bake.embree": _EXACT_PEAKS,
        "prt_torch.scene.peaks -> prt_torch.bake.embree": _EXACT_PEAKS,
        "prt_torch.player.scene -> prt_torch.scene.truth": _EXACT_PEAKS,
        "prt_torch.scene.peaks -> prt_torch.scene.truth": _EXACT_PEAKS,
        "prt_torch.bake.peaks -> prt_torch.bake.embree": _EXACT_PEAKS,
        "prt_torch.rig.vertex_frames: sklearn": _MEAN_SHIFT,
        "prt_torch.brdf.factor: sklearn": _RPO_BUILD,
        "prt_torch.rig.material: sklearn": _MATERIAL_RPO,
        "prt_torch.rig.random_pose: sklearn": "the cpca training-pose sampler (k-means) runs in the bake's plan only",
        "prt_torch.rundir -> prt_torch.models.visibility": _LOAD_MODEL,
        "prt_torch.rundir -> prt_torch.bake.store": _DATASET,
        "prt_torch.commands.light -> prt_torch.sg.lighting": _SG_LIGHT,
        "prt_torch.commands.light: healpy": _SG_LIGHT,
        "prt_torch.commands.light: torch": _SG_LIGHT,
        "prt_torch.sg.split -> prt_torch.sg.lighting": _SG_SPLIT,
        "prt_torch.vct.play -> prt_torch.vct.player": "`prt play --renderer sg` (SG lighting + voxel cone tracing) "
                                                      "needs torch and healpy",
        "prt_torch.cloth.player -> prt_torch.cloth.cache": "`prt play --sequence` reads the run's vertex cache "
                                                                "(zarr, extra bake); positions arrays play without it",
    },
    "sg": {
        "prt_torch.brdf.factor: sklearn": "SG BRDF fits use hemisphere_rule only, not the RPO factorisation (SVD)",
    },
    "train": {
        "prt_torch.cloth.bake -> prt_torch.cloth.simulate": "prt train reads a cloth run's dataset; simulating "
                                                                 "(mujoco) is prt bake's",
        "prt_torch.player.player -> prt_torch.bake.embree": _EXACT_PEAKS,
        "prt_torch.player.peaks -> prt_torch.bake.embree": _EXACT_PEAKS,
        "prt_torch.bake.peaks -> prt_torch.bake.embree": _EXACT_PEAKS,
        "prt_torch.sg.split -> prt_torch.sg.lighting": _SG_SPLIT,
    },
    "export": {
        "prt_torch.cloth.bake -> prt_torch.cloth.simulate": "prt export of a cloth run reads its subject and "
                                                                 "dataset (export.deformable); simulating (mujoco) "
                                                                 "is prt bake's",
        "prt_torch.bake.peaks -> prt_torch.bake.embree": _EXACT_PEAKS,
    },
    "bake": {
        "prt_torch.sh.basis: torch": _TORCH_TENSORS,
        "prt_torch.sh.rotation: torch": _TORCH_TENSORS,
        "prt_torch.sh.zonal: torch": _TORCH_TENSORS,
        "prt_torch.rig.material -> prt_torch.brdf": _MATERIAL_RPO,
        "prt_torch.rig.material -> prt_torch.brdf.rpo": _MATERIAL_RPO,
        "prt_torch.rundir -> prt_torch.models.visibility": _LOAD_MODEL,
    },
}


# -- pyproject ---------------------------------------------------------------------------------------


def canonical(name: str) -> str:
    """PEP 503 normalised distribution name."""
    return re.sub(r"[-_.]+", "-", name).lower()


@cache
def pyproject() -> dict:
    with open(REPO / "pyproject.toml", "rb") as f:
        return tomllib.load(f)


def _installed_extra_requirements(dist: str, extra: str) -> set[str]:
    """Distributions that the installed ``dist`` requires for its ``extra`` (e.g. dask[distributed])."""
    out = set()
    for r in md.requires(dist) or []:
        req = Requirement(r)
        if req.marker is not None and req.marker.evaluate({"extra": extra}) and \
                not req.marker.evaluate({"extra": ""}):
            out.add(canonical(req.name))
    return out


def declared(*extras: str) -> set[str]:
    """Canonical distribution names of the base install plus ``extras`` (self-references and the
    extras of required distributions expanded)."""
    proj = pyproject()["project"]
    table = proj.get("optional-dependencies", {})
    out: set[str] = set()
    todo = [("", r) for r in proj["dependencies"]] + [(e, r) for e in extras for r in table[e]]
    seen_extras = set(extras)
    while todo:
        _, spec = todo.pop()
        req = Requirement(spec)
        name = canonical(req.name)
        if name == PROJECT:
            for e in req.extras - seen_extras:
                seen_extras.add(e)
                todo += [(e, r) for r in table[e]]
            continue
        out.add(name)
        for e in req.extras:
            out |= _installed_extra_requirements(req.name, e)
    return out


def requirement_specs(*extras: str) -> dict[str, str]:
    """Canonical name -> requirement string, for the base (no extras) or the listed extras."""
    proj = pyproject()["project"]
    specs = proj["dependencies"] if not extras else [r for e in extras for r in proj["optional-dependencies"][e]]
    return {canonical(Requirement(r).name): r for r in specs}


# -- imports -> distributions ----------------------------------------------------------------------


@cache
def _packages() -> dict[str, list[str]]:
    return md.packages_distributions()


@cache
def distributions_of(top: str) -> frozenset[str]:
    """Canonical names of the installed distributions that provide the top-level module ``top``."""
    names = set(_packages().get(top, []))
    if not names:  # e.g. a bare extension module, OpenEXR.cpython-311-x86_64-linux-gnu.so (py3.11)
        for dist in md.distributions():
            for f in dist.files or ():
                if (len(f.parts) > 1 and f.parts[0] == top) or (len(f.parts) == 1 and inspect.getmodulename(f.name)
                                                                  == top):
                    names.add(dist.metadata["Name"])
                    break
    return frozenset(canonical(n) for n in names)


def is_third_party(top: str) -> bool:
    return top not in LOCAL and top not in sys.stdlib_module_names and top != "__future__"


# -- the static walk ---------------------------------------------------------------------------------


@dataclass(frozen=True)
class Imp:
    """One import statement target: ``module`` (absolute) imported by ``importer``; ``lazy``: inside a function."""

    importer: str
    module: str
    names: tuple[str, ...]
    lazy: bool
    line: int

    @property
    def top(self) -> str:
        return self.module.split(".")[0]


def module_path(mod: str, root: Path = REPO) -> Path | None:
    """Source file of a project module (``pkg/__init__.py`` or ``pkg/mod.py``), or None."""
    p = root.joinpath(*mod.split("."))
    if (p / "__init__.py").is_file():
        return p / "__init__.py"
    if p.with_suffix(".py").is_file():
        return p.with_suffix(".py")
    return None


@cache
def imports_of(mod: str) -> tuple[Imp, ...]:
    """Every import statement of ``mod`` (module level and inside functions; not under ``if TYPE_CHECKING``)."""
    path = module_path(mod)
    assert path is not None, mod
    package = mod if path.name == "__init__.py" else mod.rpartition(".")[0]
    out: list[Imp] = []

    def visit(node: ast.AST, lazy: bool) -> None:
        for ch in ast.iter_child_nodes(node):
            if isinstance(ch, ast.If) and "TYPE_CHECKING" in ast.unparse(ch.test):
                for c in ch.orelse:
                    visit(ast.Module(body=[c], type_ignores=[]), lazy)
                continue
            if isinstance(ch, ast.Import):
                out.extend(Imp(mod, a.name, (), lazy, ch.lineno) for a in ch.names)
            elif isinstance(ch, ast.ImportFrom):
                if ch.level:
                    base = package.split(".")
                    base = base[:len(base) - (ch.level - 1)]
                    target = ".".join(base + ([ch.module] if ch.module else []))
                else:
                    target = ch.module or ""
                out.append(Imp(mod, target, tuple(a.name for a in ch.names), lazy, ch.lineno))
            visit(ch, lazy or isinstance(ch, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda)))

    tree = ast.parse(path.read_text(), str(path))
    visit(tree, False)
    out.extend(_table_imports(mod, tree))
    return tuple(out)


def _table_imports(mod: str, tree: ast.Module) -> list[Imp]:
    """The hooks of ``mod``'s stage tables (module-level ``NAME: StageTable = {...}``, :mod:`prt_torch.plugins`):
    each ``"module:attr"`` reference is an import the stage makes lazily (``plugins.load``) when it runs."""
    out = []
    for node in tree.body:
        if isinstance(node, ast.AnnAssign) and ast.unparse(node.annotation) == "StageTable" and node.value:
            for c in ast.walk(node.value):
                if isinstance(c, ast.Constant) and isinstance(c.value, str) and ":" in c.value:
                    target, _, attr = c.value.partition(":")
                    out.append(Imp(mod, target, (attr,), True, c.lineno))
    return out


def local_targets(imp: Imp) -> list[str]:
    """Project modules an import loads: the module, its parent packages, and ``from m import sub`` submodules."""
    parts = imp.module.split(".")
    mods = [".".join(parts[:i]) for i in range(1, len(parts) + 1)]
    mods += [f"{imp.module}.{n}" for n in imp.names if n != "*"]
    return [m for m in mods if module_path(m) is not None]


@dataclass
class Walk:
    modules: set[str]
    third_party: list[Imp]  # imports of non-project, non-stdlib modules met on the walk
    skipped: set[str]  # UNUSED_LAZY keys that cut something


def walk(roots: tuple[str, ...], unused: dict[str, str] | None = None, module_level_only: bool = False) -> Walk:
    """Transitive closure of ``roots`` through project imports; ``unused`` lazy imports/edges are not followed."""
    unused = unused or {}
    seen: set[str] = set()
    third: list[Imp] = []
    skipped: set[str] = set()
    todo = list(roots)
    while todo:
        m = todo.pop()
        if m in seen:
            continue
        seen.add(m)
        for imp in imports_of(m):
            if module_level_only and imp.lazy:
                continue
            if imp.top in LOCAL:
                key = f"{m} -> {imp.module}"
                if key in unused:
                    assert imp.lazy, f"{key} is listed as unused but imported at module level (line {imp.line})"
                    skipped.add(key)
                    continue
                todo += local_targets(imp)
            elif is_third_party(imp.top):
                key = f"{m}: {imp.top}"
                if key in unused:
                    assert imp.lazy, f"{m} imports {imp.top} at module level (line {imp.line}) but it is listed " \
                                     f"as unused"
                    skipped.add(key)
                    continue
                third.append(imp)
    return Walk(seen, third, skipped)


def undeclared(w: Walk, allowed: set[str]) -> list[str]:
    """``module:line imports top (distributions)`` for every third-party import not covered by ``allowed``."""
    bad = []
    for imp in w.third_party:
        dists = distributions_of(imp.top) or {canonical(imp.top)}  # not installed here: e.g. tomli on 3.11
        if not dists & allowed:
            bad.append(f"{imp.importer}:{imp.line} imports {imp.top} (distribution {sorted(dists) or '?'})")
    return sorted(set(bad))


def all_modules(package: str) -> list[str]:
    root = REPO / package
    return sorted(".".join(p.relative_to(REPO).with_suffix("").parts).removesuffix(".__init__")
                  for p in root.rglob("*.py"))


# -- tests -------------------------------------------------------------------------------------------


def test_base_has_no_torch_and_the_pins_hold() -> None:
    base = requirement_specs()
    assert "torch" not in base and "torch" not in declared()
    assert "openexr" in base  # .exr reading is part of the base install
    for extra in ("train", "export"):
        assert requirement_specs(extra)["torch"].replace(" ", "") == "torch==2.13.0"
    for name in ("torch", "onnx", "onnxscript", "embreex", "zarr", "scikit-learn", "dask", "matplotlib"):
        assert name not in declared(), f"{name} belongs in an extra, not the base install"


def test_all_is_every_extra() -> None:
    table = pyproject()["project"]["optional-dependencies"]
    assert set(table) >= {"bake", "train", "export", "all", "dev"}
    # gpu (onnxruntime-gpu) replaces the CPU onnxruntime wheel instead of adding to it: never part of `all`
    pipeline = [e for e in table if e not in ("all", "dev", "gpu")]
    assert declared("all") == declared(*pipeline)


def test_distribution_mapping_sees_every_declared_import_name() -> None:
    # the mapping the tests rely on works here (including bare extension modules such as OpenEXR)
    for top, dist in (("cv2", "opencv-python-headless"), ("yaml", "pyyaml"), ("OpenEXR", "openexr"),
                      ("vtkmodules", "vtk"), ("sklearn", "scikit-learn")):
        assert dist in distributions_of(top), (top, distributions_of(top))


@pytest.mark.parametrize("entry", sorted(ENTRY_POINTS))
def test_entry_point_imports_are_declared(entry: str) -> None:
    extras, roots = ENTRY_POINTS[entry]
    unused = UNUSED_LAZY.get(entry, {})
    w = walk(roots, unused)
    bad = undeclared(w, declared(*extras))
    assert not bad, f"prt {entry} imports distributions not declared for it: {bad}"
    assert len(w.modules) > len(roots)  # the walk did follow prt_torch imports


@pytest.mark.parametrize("entry", sorted(UNUSED_LAZY))
def test_unused_lazy_list_is_current(entry: str) -> None:
    unused = UNUSED_LAZY[entry]
    stale = set(unused) - walk(ENTRY_POINTS[entry][1], unused).skipped
    assert not stale, f"UNUSED_LAZY[{entry!r}] lists imports the walk no longer meets (remove them): {sorted(stale)}"


def test_play_reaches_torch_only_through_listed_lazy_paths() -> None:
    roots = ENTRY_POINTS["play"][1]
    scoped = walk(roots, UNUSED_LAZY["play"])
    assert not [i for i in scoped.third_party if i.top == "torch"]
    # Unscoped, the walk does reach modules that import torch at module level (prt_torch.models via the lazy
    # RunDir.model); none of them may be reachable from the player other than through a listed lazy path.
    full = walk(roots)
    eager_torch = {i.importer for i in full.third_party if i.top == "torch" and not i.lazy}
    assert eager_torch.isdisjoint(scoped.modules)


def test_prt_help_imports_only_the_base_set() -> None:
    # `prt` imports every command module (prt_torch.cli.COMMANDS) before parsing: their module-level code
    # (the core stages' in prt_torch/commands/, a method package's where cli.COMMANDS and commands.bench.BENCHES say)
    from prt_torch.cli import COMMANDS
    from prt_torch.commands.bench import BENCHES

    cmd_modules = tuple(m for m in all_modules("prt_torch") if m.startswith("prt_torch.commands"))
    cmd_modules += tuple(sorted({*COMMANDS.values(), *BENCHES.values()} - set(cmd_modules)))
    w = walk(("prt_torch.cli", *cmd_modules), module_level_only=True)
    assert not undeclared(w, declared())


def test_every_project_import_is_declared_by_all() -> None:
    mods = tuple(m for p in PACKAGES for m in all_modules(p))
    w = walk(mods)
    assert not undeclared(w, declared("all"))


def test_test_imports_are_declared_by_all_and_dev() -> None:
    mods = tuple(m for m in all_modules("tests"))
    w = walk(mods)
    assert not undeclared(w, declared("all", "dev") | {"packaging"})  # packaging: a dependency of pytest


def _base_only_import_names() -> set[str]:
    """Top-level modules of distributions that only the extras bring (not the base install, even transitively)."""
    def closure(names: set[str]) -> set[str]:
        out, todo = set(), list(names)
        while todo:
            n = todo.pop()
            if n in out:
                continue
            out.add(n)
            try:
                reqs = md.requires(n) or []
            except md.PackageNotFoundError:
                continue
            for r in reqs:
                req = Requirement(r)
                if req.marker is None or req.marker.evaluate({"extra": ""}):
                    todo.append(canonical(req.name))
        return out

    extra_only = declared("all") - closure(declared())
    return {top for top, dists in _packages().items() if {canonical(d) for d in dists} & extra_only}


def test_player_runtime_imports_no_torch() -> None:
    forbidden = _base_only_import_names()
    assert "torch" in forbidden and "sklearn" in forbidden
    code = (
        "import json, sys\n"
        "import prt_torch.player, prt_torch.rundir, prt_torch.runtime.session\n"
        "from prt_torch.cli import main\n"
        "try:\n"
        "    main(['play', '--help'])\n"
        "except SystemExit as e:\n"
        "    assert e.code in (0, None), e.code\n"
        "print(json.dumps(sorted({m.split('.')[0] for m in sys.modules})))\n"
    )
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=REPO, timeout=120)
    assert r.returncode == 0, r.stderr
    loaded = set(json.loads(r.stdout.strip().splitlines()[-1]))
    assert "torch" not in loaded
    assert not loaded & forbidden, f"the player path imported extras-only modules: {sorted(loaded & forbidden)}"

"""No run-directory file name is spelled outside :mod:`prt_torch.rundir` (its one owner).

The names are read from ``rundir.py`` itself (its ``_NAME = "..."`` constants). In every other module of
``prt_torch``, ``train`` and ``export`` (docstrings excepted), a string literal may not contain a file
name of the run directory (``dataset.zarr``, ``export.json``, ...), and a directory name (``models``,
``rpo``, ``report``, ``compare``) may not be joined onto a path (``x / "models"``) or start a relative
path (``"models/..."``).
"""

from __future__ import annotations

import ast
import re
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
RUNDIR = REPO / "prt_torch" / "rundir.py"


def _names() -> tuple[set[str], set[str]]:
    """(file names with a suffix, bare directory names) owned by rundir.py."""
    files, dirs = set(), set()
    for node in ast.parse(RUNDIR.read_text()).body:
        if (isinstance(node, ast.Assign) and len(node.targets) == 1 and isinstance(node.targets[0], ast.Name)
                and node.targets[0].id.startswith("_") and node.targets[0].id.isupper()
                and isinstance(node.value, ast.Constant) and isinstance(node.value.value, str)):
            (files if "." in node.value.value else dirs).add(node.value.value)
    return files, dirs


def _docstrings(tree: ast.AST) -> set[int]:
    ids = set()
    for node in ast.walk(tree):
        if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)) and node.body:
            first = node.body[0]
            if isinstance(first, ast.Expr) and isinstance(first.value, ast.Constant):
                ids.add(id(first.value))
    return ids


def offending_literals(source: str, files: set[str], dirs: set[str]) -> list[tuple[int, str]]:
    tree = ast.parse(source)
    skip = _docstrings(tree)
    joined = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.BinOp) and isinstance(node.op, ast.Div) and isinstance(node.right, ast.Constant):
            joined.add(id(node.right))
    file_re = re.compile(r"(?<![\w.])(" + "|".join(re.escape(f) for f in sorted(files)) + r")(?![\w])")
    dir_re = re.compile(r"^(" + "|".join(re.escape(d) for d in sorted(dirs)) + r")/")
    bad = []
    for node in ast.walk(tree):
        if not (isinstance(node, ast.Constant) and isinstance(node.value, str)) or id(node) in skip:
            continue
        s = node.value
        if file_re.search(s) or dir_re.search(s) or (id(node) in joined and s in dirs):
            bad.append((node.lineno, s))
    return bad


def test_rundir_owns_the_names() -> None:
    files, dirs = _names()
    assert {"dataset.zarr", "character.npz", "export.json", "model.json", "frames.npz"} <= files
    assert {"models", "rpo", "report", "compare"} <= dirs


def test_no_run_directory_literal_outside_rundir() -> None:
    files, dirs = _names()
    bad = []
    for root in ("prt_torch", "train", "export"):
        for path in sorted((REPO / root).rglob("*.py")):
            if path == RUNDIR:
                continue
            bad += [f"{path.relative_to(REPO)}:{line}: {s!r}" for line, s in offending_literals(path.read_text(), files,
                                                                                                 dirs)]
    assert not bad, "run-directory names outside prt_torch/rundir.py (use a RunDir property):\n" + "\n".join(bad)


def test_checker_finds_planted_literals() -> None:
    files, dirs = _names()
    src = ('"""Docstring may say dataset.zarr."""\n'
           'p = run / "dataset.zarr"\nq = run / "models"\nr = f"{run}/export.json"\ns = "rpo/lambert.npz"\n'
           't = {"models": 1}\n')
    lines = [line for line, _ in offending_literals(src, files, dirs)]
    assert sorted(set(lines)) == [2, 3, 4, 5]  # not the docstring (1), not a dict key that happens to be "models"

"""The method packages and the stage tables that find them.

The core pipeline (``rig -> bake -> reduce/models -> fit -> export -> player``, the math below it, ``eval`` /
``compare`` on top) never imports a method package. Each stage that a method can extend owns one
:data:`StageTable`: a module-level constant mapping EVERY name of :data:`METHOD_PACKAGES` to the references
(``"prt_torch.<package>.<module>:<attr>"``) of that package's hooks for the stage, ``()`` where the package has
nothing there. The stage resolves the references with :func:`load` when it runs, so the import goes from the
method to the core, never back. ``tests/architecture/test_layers.py`` finds every ``StageTable`` and checks that it
lists every method package and names only that package's own modules.

Adding a method therefore means one package under ``prt_torch/`` plus one line in each table (docs/DESIGN.md,
"Adding a method").
"""

from __future__ import annotations

import importlib
from typing import Any

from prt_torch.errors import PrtError

#: every method package (``prt_torch.<name>``): the seed systems and local networks beside the core pipeline
METHOD_PACKAGES: tuple[str, ...] = ("s001", "transfer", "local", "shexp", "vct", "heightfield", "cloth")

#: a stage's table: method package -> the ``"module:attr"`` references of its hooks for that stage
StageTable = dict[str, tuple[str, ...]]


def load(ref: str) -> Any:
    """The object a ``"prt_torch.pkg.module:attr"`` reference names (the module imported on first use)."""
    module, sep, attr = ref.partition(":")
    if not sep or not attr:
        raise PrtError(f"stage table reference {ref!r} is not 'module:attr'")
    return getattr(importlib.import_module(module), attr)


def hooks(table: StageTable) -> list[Any]:
    """Every hook of ``table``, loaded, in the table's own order: a stage runs (and shows) its hooks in the order
    its table lists them."""
    return [load(ref) for refs in table.values() for ref in refs]

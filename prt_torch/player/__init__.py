"""The run-time player (onnxruntime + numpy + pyvista; never torch): :class:`Player`.

The exports are imported on first access (module ``__getattr__``, PEP 562): ``from prt_torch.player import Player``
works as before, while the light modules of the package (:mod:`prt_torch.player.renderers`, the ``--renderer``
table ``prt play`` builds its parser from) import without the player.
"""

from __future__ import annotations

import sys
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from prt_torch.player.player import Player, PlayResult
    from prt_torch.player.posing import PoseBatch, Poser

#: exported name -> its submodule (imported on first access)
_LAZY: dict[str, str] = {
    "PlayResult": "prt_torch.player.player",
    "Player": "prt_torch.player.player",
    "PoseBatch": "prt_torch.player.posing",
    "Poser": "prt_torch.player.posing",
}

__all__ = ["PlayResult", "PoseBatch", "Player", "Poser"]


def __getattr__(name: str) -> Any:
    """The exports, imported on first access (module docstring)."""
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    # plain imports (not importlib) so that tests/test_packaging.py sees these lazy edges
    if module == "prt_torch.player.player":
        import prt_torch.player.player
    else:
        import prt_torch.player.posing  # noqa: F401
    value = getattr(sys.modules[module], name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted({*globals(), *_LAZY})

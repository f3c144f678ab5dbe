"""SH exponentiation of sphere blockers (Ren et al. 2006; seed 003 sec. 3 eq. 3, sec. 7): log-visibility
table of one sphere, OL / HYB SH exponentials, batched visibility of receivers under spheres (torch, ONNX)."""

from __future__ import annotations

import importlib
import sys
import types
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from prt_torch.shexp.exponential import SHExponential, sh_exp
    from prt_torch.shexp.tables import cap_complement_zh, cos_log_table, exp_reference, log_visibility_table, ol_table
    from prt_torch.shexp.visibility import ShexpVisibility, log_visibility_sum, shexp_visibility
    from prt_torch.shexp.zonal_sum import zonal_sum

#: exported name -> its submodule, imported on first access (module ``__getattr__``, PEP 562): importing one
#: submodule (a ``prt`` command or bench module, a stage hook) runs this package without importing torch
_LAZY: dict[str, str] = {
    "SHExponential": "prt_torch.shexp.exponential",
    "sh_exp": "prt_torch.shexp.exponential",
    "cap_complement_zh": "prt_torch.shexp.tables",
    "cos_log_table": "prt_torch.shexp.tables",
    "exp_reference": "prt_torch.shexp.tables",
    "log_visibility_table": "prt_torch.shexp.tables",
    "ol_table": "prt_torch.shexp.tables",
    "ShexpVisibility": "prt_torch.shexp.visibility",
    "log_visibility_sum": "prt_torch.shexp.visibility",
    "shexp_visibility": "prt_torch.shexp.visibility",
    "zonal_sum": "prt_torch.shexp.zonal_sum",
}

__all__ = ["SHExponential", "ShexpVisibility", "cap_complement_zh", "cos_log_table", "exp_reference",
           "log_visibility_sum", "log_visibility_table", "ol_table", "sh_exp", "shexp_visibility", "zonal_sum"]


def __getattr__(name: str) -> Any:
    """The exports, imported on first access (``from prt_torch.shexp import X`` works as before)."""
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted({*globals(), *_LAZY})


class _Package(types.ModuleType):
    """This package, keeping an export whose name is also its submodule's (``zonal_sum``): importing the submodule
    binds the module on the package, and the export (the function of the same name) is kept instead, as the eager
    ``from prt_torch.shexp.zonal_sum import zonal_sum`` did."""

    def __setattr__(self, name: str, value: Any) -> None:
        if isinstance(value, types.ModuleType) and _LAZY.get(name) == value.__name__:
            value = getattr(value, name)
        super().__setattr__(name, value)


sys.modules[__name__].__class__ = _Package

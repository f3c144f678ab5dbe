"""SH exponentiation of sphere blockers (Ren et al. 2006; seed 003 sec. 3 eq. 3, sec. 7): log-visibility
table of one sphere, OL / HYB SH exponentials, batched visibility of receivers under spheres (torch, ONNX)."""

from __future__ import annotations

from typing import TYPE_CHECKING

from prt_torch.lazy import lazy_exports

if TYPE_CHECKING:
    from prt_torch.shexp.exponential import SHExponential, sh_exp
    from prt_torch.shexp.tables import cap_complement_zh, cos_log_table, exp_reference, log_visibility_table, ol_table
    from prt_torch.shexp.visibility import ShexpVisibility, log_visibility_sum, shexp_visibility
    from prt_torch.shexp.zonal_sum import zonal_sum

#: submodule -> the names exported from it, imported on first access (:func:`prt_torch.lazy.lazy_exports`):
#: importing one submodule (a ``prt`` command or bench module, a stage hook) runs this package without torch
_EXPORTS: dict[str, tuple[str, ...]] = {
    "prt_torch.shexp.exponential": ("SHExponential", "sh_exp"),
    "prt_torch.shexp.tables": (
        "cap_complement_zh", "cos_log_table", "exp_reference", "log_visibility_table", "ol_table",
    ),
    "prt_torch.shexp.visibility": ("ShexpVisibility", "log_visibility_sum", "shexp_visibility"),
    "prt_torch.shexp.zonal_sum": ("zonal_sum",),
}

__all__ = ["SHExponential", "ShexpVisibility", "cap_complement_zh", "cos_log_table", "exp_reference",
           "log_visibility_sum", "log_visibility_table", "ol_table", "sh_exp", "shexp_visibility", "zonal_sum"]

lazy_exports(__name__, _EXPORTS)

"""The RPO catalogue scoring uses: the BRDFs that ship.

The RPO catalogue of :func:`prt_torch.brdf.rpo.builtin_rpo` (``lambert``; ``phong`` = exponent 16, kd 0.3,
ks 0.7; ``k = 8`` terms), read from the run's exported ``rpo/<name>.npz`` when the run is exported (the very
files the player loads), else built by the same function (:func:`shipping_rpos`).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING

from prt_torch.errors import check

if TYPE_CHECKING:
    from prt_torch.brdf.rpo import RPO
    from prt_torch.rundir import RunDir

#: shipped BRDFs scored by eval/compare: (diffuse, glossy)
DIFFUSE, GLOSSY = "lambert", "phong"
BRDFS: tuple[str, ...] = (DIFFUSE, GLOSSY)
#: BRDF terms of the shipped RPOs (``prt export``'s ``n_terms``)
N_TERMS = 8


def shipping_rpos(order: int, run: RunDir | None = None, names: Sequence[str] = BRDFS,
                  n_terms: int = N_TERMS) -> dict[str, RPO]:
    """The shipped RPOs by name: the run's exported ``rpo/<name>.npz`` when the export lists it (verified
    against the export's hashes, what the player loads), else :func:`prt_torch.brdf.rpo.builtin_rpo` (what
    ``prt export`` writes) of ``order`` and ``n_terms``."""
    from prt_torch.brdf.rpo import RPO, builtin_rpo

    exported: set[str] = set()
    if run is not None and run.export_json.is_file():
        exported = set(run.export_meta().get("rpo_files", {}))  # export_meta verifies every file's sha256
    out = {}
    for name in names:
        path = run.rpo_path(name) if run is not None and name in exported else None
        rpo = RPO.load(path) if path is not None and path.is_file() else builtin_rpo(name, order=order, k=n_terms)
        check(rpo.order == order, f"RPO {name!r} has order {rpo.order}, the run {order}")
        out[name] = rpo
    return out

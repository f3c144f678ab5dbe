"""The RPO catalogue scoring uses: the BRDFs that ship.

The RPO catalogue of :func:`prt_torch.brdf.rpo.builtin_rpo` (``lambert``; ``phong`` = exponent 16, kd 0.3,
ks 0.7; ``k = 8`` terms), read from the run's exported ``rpo/<name>.npz`` when the run is exported (the very
files the player loads), else built by the same function (:func:`shipping_rpos`).

A character with its own material (a glTF character) plays ``material`` by default
(:func:`prt_torch.player.material.default_brdf`): :func:`player_brdfs` adds it, the player's very RPO file
(:func:`prt_torch.rig.material.material_rpo_file`, the run's cache) and the analytic Cook-Torrance it was built from
(:func:`prt_torch.rig.material.material_brdf`, for the Monte-Carlo reference).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

from prt_torch.brdf.rpo import DEFAULT_TERMS
from prt_torch.errors import PrtError, check, warn

if TYPE_CHECKING:
    from prt_torch.brdf.rpo import RPO
    from prt_torch.rundir import RunDir

#: shipped BRDFs scored by eval/compare: (diffuse, glossy)
DIFFUSE, GLOSSY = "lambert", "phong"
BRDFS: tuple[str, ...] = (DIFFUSE, GLOSSY)


def shipping_rpos(order: int, run: RunDir | None = None, names: Sequence[str] = BRDFS,
                  n_terms: int = DEFAULT_TERMS) -> dict[str, RPO]:
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


def player_brdfs(order: int, run: RunDir | None, character: Any, names: Sequence[str] = BRDFS,
                 n_terms: int | None = None) -> tuple[dict[str, RPO], dict[str, Any]]:
    """``(rpos {name: RPO}, brdfs {name: analytic BRDF})`` scored for ``character``: :func:`shipping_rpos` of ``names``
    (analytic: :func:`prt_torch.brdf.rpo.builtin_brdf`), then, for a character with its own material
    (:func:`prt_torch.player.material.has_own_material`), ``material``: the RPO file the player plays (built once and
    cached in the run, :func:`prt_torch.rig.material.material_rpo_file`) and the analytic Cook-Torrance with the
    parameters it was built from (:func:`prt_torch.rig.material.material_brdf`). ``n_terms``: the export's, else
    :data:`~prt_torch.brdf.rpo.DEFAULT_TERMS`. A material RPO that cannot be built (no scikit-learn) is left out with
    a warning, as the player falls back to the catalogue."""
    from prt_torch.brdf.rpo import RPO, builtin_brdf
    from prt_torch.player.material import has_own_material
    from prt_torch.rig.material import MATERIAL_BRDF, character_material, material_brdf, material_rpo_file

    if n_terms is None:
        meta = run.export_meta() if run is not None and run.export_json.is_file() else {}
        n_terms = int(meta.get("n_terms", DEFAULT_TERMS))
    rpos = shipping_rpos(order, run, names, n_terms)
    brdfs = {n: builtin_brdf(n) for n in rpos}
    if has_own_material(character):
        material = character_material(character)
        try:
            path = material_rpo_file(material, order, n_terms, run=run)
        except PrtError as exc:
            warn(f"{exc}; scoring without the material's own BRDF")
            return rpos, brdfs
        assert path is not None
        rpo = RPO.load(path)
        check(rpo.order == order, f"the material's RPO {path} has order {rpo.order}, the run {order}")
        rpos[MATERIAL_BRDF] = rpo
        brdfs[MATERIAL_BRDF] = material_brdf(material)
    return rpos, brdfs

"""The shading rule of the learned transfer (seed 000) + subsurface, shared by ``prt compare``'s
``learned_transfer`` / ``baked_transfer`` and ``prt play --renderer transfer`` (numpy only)::

    L_out = albedo * (L . t) + sss_tint * (L . t_sss),      sss_tint = albedo / mean(albedo)

``albedo`` is the BRDF's RPO tint, ``L`` the world-frame SH lighting, ``t`` the (learned or baked) diffuse transfer
with its interreflection bounces, ``t_sss`` the subsurface exit-radiance transfer (absent: no second term). The
bake's ``subsurface`` array is already the exit radiance per unit incident radiance of its dipole material
(:mod:`prt_torch.bake.subsurface`: the reduced albedo ``a'``, the Fresnel transmittances ``(1 - F_dr)^2`` and the
dipole reflectance of ``bake.subsurface``'s ``sigma_a``, ``sigma_s_prime``, ``eta`` are in it, for ONE scalar
channel, by default Jensen 2001's skin1 green), so its magnitude is not scaled again: the tint only gives that channel
the material's colour (the albedo's chromaticity, mean 1: a grey material keeps the baked magnitude in every
channel). Also here (numpy only, so the torch-free player reads them without the graph builder
:mod:`prt_torch.transfer.graph`): the graph's output names and :func:`exported_transfer`, an exported run's
current transfer-graph entry.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from prt_torch.errors import ArtifactError, check
from prt_torch.rundir import file_sha256
from prt_torch.shapes import check_shape

#: the learned arrays a transfer graph may carry, in output order
ARRAYS: tuple[str, ...] = ("transfer", "subsurface")


def radiance_output(array: str) -> str:
    """The graph output holding ``L . <array>``: ``radiance`` for ``transfer``, ``<array>_radiance`` else."""
    return "radiance" if array == "transfer" else f"{array}_radiance"


def graph_outputs(arrays: tuple[str, ...] | list[str]) -> tuple[str, ...]:
    """Output names of the graph of ``arrays``: per array the transfer then its radiance."""
    return tuple(n for a in arrays for n in (a, radiance_output(a)))


def subsurface_tint(albedo: Any) -> np.ndarray:
    """``(3,)`` float32 colour of the subsurface term: ``albedo / mean(albedo)`` (module doc)."""
    a = np.asarray(albedo, dtype=np.float64).reshape(-1)
    check(a.shape == (3,) and bool(np.isfinite(a).all()) and bool((a >= 0).all()) and a.sum() > 0,
          f"subsurface tint: the albedo must be 3 finite values >= 0, not all 0, got {np.asarray(albedo).tolist()}")
    return (a / a.mean()).astype(np.float32)


def light_dot(t: Any, light_sh: Any) -> np.ndarray:
    """``(B, V, 3)`` float32 ``L . t`` of transfer ``t (B, V, C)`` and world-frame SH lighting ``light_sh (C', 3)``
    over their first ``min(C, C')`` coefficients (numpy; the graph's ``radiance`` output)."""
    t = np.asarray(t, dtype=np.float32)
    light_sh = np.asarray(light_sh, dtype=np.float32)
    check_shape(t, "B V C", name="transfer shading: t")
    check_shape(light_sh, "C_light 3", name="transfer shading: lighting")
    c = min(t.shape[2], light_sh.shape[0])
    return np.matmul(t[..., :c], light_sh[:c])


def light_input(light_sh: Any, n_light: int) -> np.ndarray:
    """``(n_light, 3)`` float32: the graph's ``light`` input from world-frame SH lighting ``light_sh (C, 3)``,
    its first ``n_light`` coefficients, zero padded when it has fewer."""
    src = np.asarray(light_sh, dtype=np.float32)[:n_light]
    out = np.zeros((n_light, 3), np.float32)
    out[: len(src)] = src
    return out


def transfer_shading(radiance: Any, albedo: dict[str, Any], sss_radiance: Any = None) -> dict[str, np.ndarray]:
    """``{brdf: (B, V, 3)}`` float32 ``albedo * (L . t) + subsurface_tint(albedo) * (L . t_sss)`` (the module's
    rule) from the unit-albedo ``radiance = L . t (B, V, 3)`` and, when the run has it, ``sss_radiance = L . t_sss``
    (``None``: no subsurface term)."""
    rad = np.asarray(radiance, dtype=np.float32)
    check(rad.ndim == 3 and rad.shape[2] == 3, f"transfer shading: radiance must be (B, V, 3), got {rad.shape}")
    sss = None if sss_radiance is None else np.asarray(sss_radiance, dtype=np.float32)
    check(sss is None or sss.shape == rad.shape,
          f"transfer shading: subsurface radiance {None if sss is None else sss.shape} != radiance {rad.shape}")
    out = {}
    for b, a in albedo.items():
        a = np.asarray(a, dtype=np.float32).reshape(3)
        r = rad * a
        if sss is not None:
            r = r + sss * subsurface_tint(a)
        out[b] = r
    return out


def exported_transfer(run: Any) -> dict[str, Any] | None:
    """``export.json``'s verified ``transfer`` entry of an exported run (None: not exported with one, or exported
    from another ``transfer.json`` than the run's current one: a retrained run needs ``prt export``)."""
    if not run.export_json.is_file():
        return None
    try:
        meta = run.export_meta()
    except ArtifactError:
        return None
    entry = meta.get("transfer")
    if not isinstance(entry, dict) or not isinstance(entry.get("file"), str):
        return None
    p = run.inside(entry["file"])
    if p is None or not p.is_file() or not run.transfer_json.is_file():
        return None
    return entry if entry.get("transfer_json_sha256") == file_sha256(run.transfer_json) else None

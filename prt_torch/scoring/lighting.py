"""The lights scoring uses: the player's lighting, in every vertex frame, and the unshadowed reference.

* **Lighting**: the player's (:func:`prt_torch.player.lighting.load_lighting`): the SH of the environment
  (order of the run) multiplied by the player's sinc window, then ``K = 3`` ZH lobes fitted to that
  *windowed* SH. Two lighting paths are reported side by side (:data:`PATHS`, :func:`local_lighting`):

  - ``exact``: the windowed SH ``Lighting.sh (C, 3)`` rotated into every vertex frame exactly with the
    SH rotation blocks of :func:`prt_torch.sh.rotation.sh_rotation_blocks` (``l_local = D(F) l``). This
    is the best any order-``n`` SH shading of that lighting can do: no lobe fit.
  - ``lobes``: the ZH lobes the player ships, rotated into the frames with
    :func:`prt_torch.shade.lobes.rotate_lobes_to_frames` (what ``shading.onnx`` computes).

  Both use the same windowed SH, so ``lobes`` vs ``exact`` isolates the error of the 3-lobe fit.
* **Lights**: ``sky`` = the player's default procedural sun + sky (``load_lighting(None, order)``), and
  ``uffizi`` / ``mondello`` from ``../shared/data/envmaps`` when present (:func:`shipping_lights`).
* **Unshadowed visibility**: the player's unoccluded hemisphere in the dataset's below-horizon convention
  (:func:`unshadowed_visibility`).
"""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from prt_torch.errors import check

if TYPE_CHECKING:
    import torch

    from prt_torch.player.lighting import Lighting

#: lighting paths (see the module docstring)
PATHS: tuple[str, ...] = ("exact", "lobes")
#: the player's default light (procedural sun + sky)
PLAYER_LIGHT = "sky"
#: optional environment maps under ``<shared data>/envmaps``
ENVMAPS = {"uffizi": "uffizi.hdr", "mondello": "spiaggia_di_mondello_1k.hdr"}


def shared_data_dir() -> Path | None:
    """``$PRT_SHARED/data`` or ``../shared/data`` next to the repository (or the working directory), when present."""
    env = os.environ.get("PRT_SHARED")
    cands = [Path(env) / "data"] if env else []
    cands.append(Path(__file__).resolve().parents[2].parent / "shared" / "data")
    cands.append(Path.cwd().parent / "shared" / "data")
    return next((c for c in cands if c.is_dir()), None)


def shipping_lights(order: int, shared_data: Path | None = None, names: Sequence[str] | None = None,
                    n_lobes: int = 3) -> dict[str, Lighting]:
    """The player's lightings by name: ``sky`` (its default) plus the env maps of :data:`ENVMAPS` found under
    ``shared_data/envmaps`` (skipped when absent). ``names`` restricts the set (unknown names: PrtError)."""
    from prt_torch.player.lighting import load_lighting

    known = [PLAYER_LIGHT, *ENVMAPS]
    for n in names or ():
        check(n in known, f"unknown light {n!r}: expected one of {known}")
    want = list(names) if names else known
    out: dict[str, Lighting] = {}
    for name in want:
        if name == PLAYER_LIGHT:
            out[name] = load_lighting(None, order, n_lobes)
            continue
        path = Path(shared_data) / "envmaps" / ENVMAPS[name] if shared_data is not None else None
        if path is not None and path.is_file():
            out[name] = load_lighting(path, order, n_lobes)
    return out


def local_lighting(lighting: Lighting, frames: torch.Tensor, path: str) -> torch.Tensor:
    """Local-frame SH lighting ``(N, C, 3)`` of a player :class:`Lighting` at ``frames (N, 3, 3)`` (torch,
    rotations, rows t, b, n), by lighting ``path`` (``exact``: ``D(F) sh``; ``lobes``: the ZH lobes)."""
    import torch

    from prt_torch.sh.basis import order_from_coeffs
    from prt_torch.sh.rotation import sh_rotation_blocks
    from prt_torch.shade.lobes import rotate_lobes_to_frames

    dt = frames.dtype
    if path == "lobes":
        dirs = torch.as_tensor(np.asarray(lighting.dirs, dtype=np.float64))
        dirs = dirs / dirs.norm(dim=-1, keepdim=True)
        return rotate_lobes_to_frames(dirs.to(dt), torch.as_tensor(np.asarray(lighting.coeffs), dtype=dt), frames,
                                      check=False)
    check(path == "exact", f"unknown lighting path {path!r}: expected one of {list(PATHS)}")
    sh = torch.as_tensor(np.asarray(lighting.sh, dtype=np.float64), dtype=dt)  # (C, 3)
    order = order_from_coeffs(sh.shape[0])
    blocks = sh_rotation_blocks(frames, order, check=False)
    return torch.cat([blocks[l] @ sh[l * l:(l + 1) * (l + 1)] for l in range(order)], dim=-2)


def unshadowed_visibility(order: int, below_horizon: str | Mapping[str, Any] | None = "zero") -> np.ndarray:
    """``(C,)`` float32: the player's unshadowed visibility in the dataset's convention: the SH of the
    upper-hemisphere indicator (``"zero"``) or the constant 1 (``"one"``).

    ``below_horizon``: the convention, or a dataset's attributes / ``attrs["bake"]`` dict (missing: ``"zero"``).
    """
    from prt_torch.bake.store import below_horizon_of
    from prt_torch.player.lighting import hemisphere_visibility

    if below_horizon is None or isinstance(below_horizon, Mapping):
        below_horizon = below_horizon_of(dict(below_horizon or {}))
    return hemisphere_visibility(order, below_horizon)

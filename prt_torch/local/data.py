"""The local data file of a run shipping a local visibility network (``RunDir.local_data_path``, ``local.npz``):
written by ``prt export`` (:func:`prt_torch.local.graph.ship_local`), read by the player. numpy only (never
torch): the player imports this module.

Keys: ``neighbours (V, S)``, the model's neighbour indices (:func:`prt_torch.local.models.neighbour_pattern`), int16
up to 32,767 vertices, else int32.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from prt_torch.errors import PrtError, check
from prt_torch.io import atomic_path
from prt_torch.rundir import RunDir
from prt_torch.shapes import check_shape


def neighbour_dtype(n_vertices: int) -> Any:
    """int16 indices up to 32,767 vertices, else int32."""
    return np.int16 if n_vertices <= np.iinfo(np.int16).max + 1 else np.int32


def write_neighbours(run: RunDir, neighbours: np.ndarray) -> int:
    """Write ``neighbours (V, S)`` atomically to ``run.local_data_path``; returns the bytes of the stored array."""
    nb = np.asarray(neighbours)
    stored = nb.astype(neighbour_dtype(nb.shape[0]))
    with atomic_path(run.local_data_path) as tmp:
        with open(tmp, "wb") as fh:
            np.savez(fh, neighbours=stored)
    return int(stored.nbytes)


def load_neighbours(run: RunDir) -> np.ndarray:
    """``(V, S)`` int32 neighbour indices of the shipped local model (one-line error when missing or damaged)."""
    path = run.local_data_path
    if not path.is_file():
        raise PrtError(f"{path} not found: run `prt export {run.path}`")
    try:
        with np.load(path) as d:
            nb = np.asarray(d["neighbours"], dtype=np.int32)
    except Exception as exc:  # noqa: BLE001 - any read problem is a damaged file
        raise PrtError(f"{path}: not a local model data file ({type(exc).__name__})") from None
    check_shape(nb, "V S", name=f"{path}: neighbours")
    check(nb.size > 0, f"{path}: neighbours must be (V, S), got {nb.shape}")
    return nb

"""The deform data file of a deformable run (``RunDir.deform_path``, ``.npz``): written by ``prt export``
(:func:`prt_torch.cloth.export.ship_deformable`), read by the player. numpy only (never torch): the player
imports this module.

Keys: the frame operator's arrays (:meth:`prt_torch.deform.frames.FrameOperator.arrays`, prefixed ``op_``),
``edges (E, 4)`` int64 (the cloth's interior edges in subject vertex indices), ``cloth_slice (2,)`` (start, stop),
``n_body_features ()`` (0: no body input).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from prt_torch.errors import PrtError, check
from prt_torch.io import atomic_path
from prt_torch.rundir import RunDir


def write_deform_data(run: RunDir, spec: Any) -> None:
    """Write the deform data of ``spec`` (a :class:`prt_torch.cloth.export.DeformSpec`: ``operator``, ``edges``,
    ``cloth_slice``, ``n_body_features``) atomically to ``run.deform_path``."""
    arrays = {f"op_{k}": np.asarray(v) for k, v in spec.operator.arrays().items()}
    s = spec.cloth_slice
    with atomic_path(run.deform_path) as tmp:
        with open(tmp, "wb") as f:
            np.savez(f, edges=np.asarray(spec.edges, dtype=np.int64),
                     cloth_slice=np.array([s.start or 0, s.stop], dtype=np.int64),
                     n_body_features=np.array(int(spec.n_body_features), dtype=np.int64), **arrays)


@dataclass
class DeformData:
    """The deform data as the player reads it (numpy only): ``operator`` (FrameOperator), ``edges (E, 4)``,
    ``cloth_slice``, ``n_body_features``."""

    operator: Any
    edges: np.ndarray
    cloth_slice: slice
    n_body_features: int

    @classmethod
    def load(cls, path: Any) -> DeformData:
        from prt_torch.deform.frames import FrameOperator

        p = Path(path)
        check(p.is_file(), f"deform data missing: {p} (run `prt export` on the deformable run)")
        try:
            with np.load(p, allow_pickle=False) as z:
                d = {k: np.asarray(z[k]) for k in z.files}
        except (OSError, ValueError) as exc:
            raise PrtError(f"{p}: unreadable deform data ({str(exc).splitlines()[0][:120]})") from None
        for key in ("edges", "cloth_slice", "n_body_features"):
            check(key in d, f"{p}: missing {key!r}: run `prt export` again")
        op = FrameOperator.from_arrays({k[3:]: v for k, v in d.items() if k.startswith("op_")})
        a, b = (int(x) for x in d["cloth_slice"])
        return cls(op, d["edges"].astype(np.int64), slice(a, b), int(d["n_body_features"]))

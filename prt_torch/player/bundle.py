"""Everything the player reads from an exported run directory, checked for consistency.

``runs/NAME/``: ``export.json`` (written by :func:`prt_torch.export.export_run`), ``character.npz``,
``frames.npz`` (cluster labels / axes / bones for the local vertex frames), ``visibility.onnx``,
``shading.onnx``, ``fused.onnx`` and ``rpo/<name>.npz``. numpy + onnxruntime only.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from prt_torch.errors import PrtError, check
from prt_torch.runtime.session import OrtGraph

EXPORT_JSON = "export.json"
FRAMES_FILE = "frames.npz"


@dataclass(frozen=True)
class RPOTensors:
    """An RPO as the shading graph takes it: ``M (k, C, C)``, ``w (k, C)`` zero-padded to the graph's
    ``k``, ``tint (3,)``, all float32, plus its ``name`` and SH ``order``."""

    name: str
    order: int
    M: np.ndarray
    w: np.ndarray
    tint: np.ndarray


def load_rpo_tensors(path: str | os.PathLike[str], order: int, n_terms: int) -> RPOTensors:
    """Load an RPO file (``prt_torch.brdf.RPO.load``, no torch) and check it fits the graph."""
    from prt_torch.brdf.rpo import RPO

    path = Path(path)
    if not path.is_file():
        raise PrtError(f"RPO file not found: {path}")
    rpo = RPO.load(path)
    M = np.asarray(rpo.M, dtype=np.float32)
    w = np.asarray(rpo.w, dtype=np.float32)
    c = order * order
    check(int(rpo.order) == order and M.shape[1:] == (c, c) and w.shape[1:] == (c,),
          f"RPO {rpo.name!r} has SH order {rpo.order} (M {M.shape}), the model order {order}")
    k = M.shape[0]
    check(k <= n_terms, f"RPO {rpo.name!r} has {k} BRDF terms, the shading graph at most {n_terms}")
    if k < n_terms:
        M = np.concatenate([M, np.zeros((n_terms - k, c, c), np.float32)])
        w = np.concatenate([w, np.zeros((n_terms - k, c), np.float32)])
    tint = np.asarray(rpo.tint, dtype=np.float32).reshape(3)
    check(bool(np.isfinite(M).all() and np.isfinite(w).all() and np.isfinite(tint).all()),
          f"RPO {rpo.name!r} contains NaN or Inf")
    return RPOTensors(str(rpo.name), order, np.ascontiguousarray(M), np.ascontiguousarray(w), tint)


class RunBundle:
    """An exported run: metadata, character, frame data, ONNX sessions and the RPO catalogue.

    Raises :class:`PrtError` when the run is not exported, files are missing, or the character /
    graphs / metadata disagree (another character, another SH order or vertex count).
    """

    def __init__(self, run_dir: str | os.PathLike[str], threads: int = 2,
                 graphs: tuple[str, ...] = ("visibility", "shading", "fused"), spinning: bool = False) -> None:
        from prt_torch.rig.character import Character

        self.run_dir = Path(run_dir)
        check(self.run_dir.is_dir(), f"run directory not found: {self.run_dir}")
        meta_path = self.run_dir / EXPORT_JSON
        check(meta_path.is_file(), f"{self.run_dir} is not exported ({EXPORT_JSON} missing): run `prt export "
                                   f"{self.run_dir}` first")
        try:
            self.meta: dict[str, Any] = json.loads(meta_path.read_text())
        except json.JSONDecodeError as exc:
            raise PrtError(f"{meta_path}: not valid JSON ({exc.msg})") from None
        self.order = int(self.meta["sh_order"])
        self.n_vertices = int(self.meta["n_vertices"])
        self.n_features = int(self.meta["n_features"])
        self.n_terms = int(self.meta["n_terms"])
        self.character = Character.load(self.run_dir / self.meta.get("character_file", "character.npz"))
        h = self.character.content_hash()
        check(h == self.meta["character_hash"],
              f"character.npz (hash {h[:12]}) is not the character the model was exported for "
              f"({self.meta['character_hash'][:12]})")
        check(self.character.num_vertices == self.n_vertices,
              f"character has {self.character.num_vertices} vertices, the model {self.n_vertices}")
        fpath = self.run_dir / FRAMES_FILE
        check(fpath.is_file(), f"frame data missing: {fpath}")
        with np.load(fpath, allow_pickle=False) as z:
            self.cluster = np.asarray(z["cluster"]).astype(np.intp)
            self.cluster_axis = np.asarray(z["cluster_axis"], dtype=np.float32)
            self.cluster_bone = np.asarray(z["cluster_bone"]).astype(np.intp)
        check(self.cluster.shape == (self.n_vertices,), f"{fpath}: cluster labels must be ({self.n_vertices},)")
        self.graphs: dict[str, OrtGraph] = {}
        for name in graphs:
            g = OrtGraph(self.run_dir / self.meta["files"][name], threads=threads, spinning=spinning)
            md = g.metadata
            for key, want in (("prt.character_hash", self.meta["character_hash"]),
                              ("prt.sh_order", str(self.order)), ("prt.n_vertices", str(self.n_vertices))):
                check(md.get(key) == want, f"{g.path.name}: metadata {key}={md.get(key)!r} does not match "
                                           f"export.json ({want!r})")
            self.graphs[name] = g
        self.rpo_files: dict[str, str] = dict(self.meta.get("rpo_files", {}))

    @property
    def brdf_names(self) -> list[str]:
        return sorted(self.rpo_files)

    def rpo(self, name_or_path: str | os.PathLike[str]) -> RPOTensors:
        """A named RPO of this run (``rpo/<name>.npz``) or an RPO file path."""
        key = str(name_or_path)
        if key in self.rpo_files:
            return load_rpo_tensors(self.run_dir / self.rpo_files[key], self.order, self.n_terms)
        p = Path(key)
        if p.suffix == ".npz" and p.is_file():
            return load_rpo_tensors(p, self.order, self.n_terms)
        raise PrtError(f"unknown BRDF {key!r}: this run has {self.brdf_names} (or pass an RPO .npz file)")

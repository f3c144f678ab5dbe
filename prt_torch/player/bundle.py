"""Everything the player reads from an exported run directory, checked for consistency.

``runs/NAME/`` (file names: :class:`prt_torch.rundir.RunDir`): the export metadata (written by
:func:`prt_torch.export.export_run`), the character, the frame data (cluster labels / axes / bones for
the vertex frames), the visibility, shading and fused ONNX graphs and the RPO catalogue. numpy +
onnxruntime only.

Integrity: the export metadata is the commit record of ``prt export``; every graph, the frame data and
every RPO file must have the sha256 it records (:meth:`prt_torch.rundir.RunDir.export_meta`), and when the
run still holds the model file it was exported from, that file must be the one exported (a re-trained run
with a stale export is refused: run ``prt export``). A player bundle shipped without model files skips
that last check.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from prt_torch.errors import MissingArtifact, PrtError, StaleArtifact, check
from prt_torch.rundir import RunDir, file_sha256
from prt_torch.runtime.session import OrtGraph


@dataclass(frozen=True)
class RPOTensors:
    """An RPO as the shading graph takes it: ``M (k, C, C)``, ``w (k, C)`` zero-padded to the graph's
    ``k``, ``tint (3,)``, all float32, plus its ``name`` and SH ``order``; ``u (k, C)`` (padded alike) the light
    factors ``M`` is built from (``M_b = sum_k u_bk Gamma_{., ., k}``: the compiled frame path's product form)."""

    name: str
    order: int
    M: np.ndarray
    w: np.ndarray
    tint: np.ndarray
    u: np.ndarray


def load_rpo_tensors(path: str | os.PathLike[str], order: int, n_terms: int) -> RPOTensors:
    """Load an RPO file (``prt_torch.brdf.RPO.load``, no torch) and check it fits the graph."""
    from prt_torch.brdf.rpo import RPO

    path = Path(path)
    if not path.is_file():
        raise MissingArtifact(f"RPO file not found: {path}")
    rpo = RPO.load(path)
    M = np.asarray(rpo.M, dtype=np.float32)
    w = np.asarray(rpo.w, dtype=np.float32)
    u = np.asarray(rpo.u, dtype=np.float32)
    c = order * order
    check(int(rpo.order) == order and M.shape[1:] == (c, c) and w.shape[1:] == (c,) and u.shape == w.shape,
          f"RPO {rpo.name!r} has SH order {rpo.order} (M {M.shape}), the model order {order}")
    k = M.shape[0]
    check(k <= n_terms, f"RPO {rpo.name!r} has {k} BRDF terms, the shading graph at most {n_terms}")
    if k < n_terms:
        M = np.concatenate([M, np.zeros((n_terms - k, c, c), np.float32)])
        w = np.concatenate([w, np.zeros((n_terms - k, c), np.float32)])
        u = np.concatenate([u, np.zeros((n_terms - k, c), np.float32)])
    tint = np.asarray(rpo.tint, dtype=np.float32).reshape(3)
    check(bool(np.isfinite(M).all() and np.isfinite(w).all() and np.isfinite(tint).all()),
          f"RPO {rpo.name!r} contains NaN or Inf")
    return RPOTensors(str(rpo.name), order, np.ascontiguousarray(M), np.ascontiguousarray(w), tint,
                      np.ascontiguousarray(u))


class RunBundle:
    """An exported run: metadata, character, frame data, ONNX sessions and the RPO catalogue.

    Raises :class:`PrtError` when the run is not exported, files are missing, or the character /
    graphs / metadata disagree (another character, another SH order or vertex count).
    """

    def __init__(self, run_dir: str | os.PathLike[str] | RunDir, threads: int = 2,
                 graphs: tuple[str, ...] = ("visibility", "shading", "fused"), spinning: bool = False,
                 device: str = "cpu") -> None:
        self.run = RunDir.of(run_dir)
        self.run_dir = self.run.path
        self.meta: dict[str, Any] = self.run.export_meta()  # verified: every file has its recorded sha256
        self._check_source_model()
        self.order = int(self.meta["sh_order"])
        self.n_vertices = int(self.meta["n_vertices"])
        self.n_features = int(self.meta["n_features"])
        self.n_terms = int(self.meta["n_terms"])
        from prt_torch.conventions import BELOW_HORIZON

        #: the visibility convention below the horizon of the exported dataset ("zero" for older exports)
        self.below_horizon = str(self.meta.get("below_horizon", "zero"))
        check(self.below_horizon in BELOW_HORIZON, f"{self.run.export_json}: below_horizon={self.below_horizon!r}, "
                                                   f"expected one of {list(BELOW_HORIZON)}")
        self.character = self.run.character(expect_hash=self.meta["character_hash"])
        check(self.character.num_vertices == self.n_vertices,
              f"character has {self.character.num_vertices} vertices, the model {self.n_vertices}")
        fpath = self.run.frames_path
        check(fpath.is_file(), f"frame data missing: {fpath}")
        with np.load(fpath, allow_pickle=False) as z:
            self.cluster = np.asarray(z["cluster"]).astype(np.intp)
            self.cluster_axis = np.asarray(z["cluster_axis"], dtype=np.float32)
            self.cluster_bone = np.asarray(z["cluster_bone"]).astype(np.intp)
            order = np.asarray(z["vertex_order"]).astype(np.intp) if "vertex_order" in z.files else None
        check(self.cluster.shape == (self.n_vertices,), f"{fpath}: cluster labels must be ({self.n_vertices},)")
        #: the fused graph's vertex order (format /3, ``fused_vertex_order: cluster``): position ``i`` holds
        #: original vertex ``vertex_order[i]``; ``None``: the original order (older exports)
        self.vertex_order: np.ndarray | None = None
        if self.meta.get("fused_vertex_order", "original") == "cluster":
            check(order is not None and order.shape == (self.n_vertices,)
                  and np.array_equal(np.sort(order), np.arange(self.n_vertices)),
                  f"{fpath}: vertex_order must be a permutation of the {self.n_vertices} vertices: run `prt export "
                  f"{self.run_dir} --force`")
            self.vertex_order = order
        #: weight precision of the exported bases (``"fp32"`` for older exports)
        self.precision = str(self.meta.get("precision", "fp32"))
        self.device = device
        self.graphs: dict[str, OrtGraph] = {}
        for name in graphs:
            g = OrtGraph(self.run.graph_path(name), threads=threads, spinning=spinning, device=device)
            md = g.metadata
            for key, want in (("prt.character_hash", self.meta["character_hash"]),
                              ("prt.sh_order", str(self.order)), ("prt.n_vertices", str(self.n_vertices))):
                check(md.get(key) == want, f"{g.path.name}: metadata {key}={md.get(key)!r} does not match "
                                           f"{self.run.export_json.name} ({want!r})")
            self.graphs[name] = g
        self.rpo_files: dict[str, str] = dict(self.meta.get("rpo_files", {}))

    def _check_source_model(self) -> None:
        """The model the export was made from, where the run still has it, must be the exported one."""
        rel = self.meta["model_file"]
        src = self.run.inside(rel)
        check(src is not None, f"{self.run.export_json}: bad key 'model_file': run `prt export {self.run_dir}` again")
        if src.is_file() and file_sha256(src) != self.meta["model_sha256"]:
            raise StaleArtifact(f"{self.run.export_json} is stale: {rel} changed since it was exported (re-trained?): "
                                f"run `prt export {self.run_dir}`")

    @property
    def brdf_names(self) -> list[str]:
        return sorted(self.rpo_files)

    def rpo(self, name_or_path: str | os.PathLike[str]) -> RPOTensors:
        """A named RPO of this run (its RPO catalogue) or an RPO file path."""
        key = str(name_or_path)
        if key in self.rpo_files:
            return load_rpo_tensors(self.run.rpo_path(key), self.order, self.n_terms)
        p = Path(key)
        if p.suffix == ".npz" and p.is_file():
            return load_rpo_tensors(p, self.order, self.n_terms)
        raise PrtError(f"unknown BRDF {key!r}: this run has {self.brdf_names} (or pass an RPO .npz file)")

"""``pca_floor`` (opt-in): an ORACLE, not a run-time method - the frames' baked (true) visibility pushed through the
trained model's own output PCA (reduce, then expand): the error every regressor with that output basis has at
least, as a row of the same table (image PSNR included). ``learned_<kind>`` minus this row is what the regressor
(pose -> reduced visibility) costs; this row is what the basis (clusters x components, ``train.output_variance`` /
``output_max_components``) costs.

The basis is the trained model's :class:`prt_torch.models.projection.OutputUnprojection`: ``basis (G, K, L)``
(scaled components, zero-padded), ``gather (V*C,)`` into the flattened ``(G, L)`` cluster outputs and ``mean``.
Reduce is the least-squares fit of each cluster's outputs, ``z_g = (y_g - mean_g) pinv(basis_g)`` (exact for the
orthogonal rows of a PCA, whatever their scale); expand is the model's own forward. Needs the frames' baked
visibility: the dataset's held-out frames (the default frame set of ``prt compare``).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from prt_torch.compare.methods.base import CompareRun, FrameBatch, FrameSet, MethodBase, register
from prt_torch.errors import PrtError


def cluster_reduce(basis: np.ndarray, gather: np.ndarray, mean: np.ndarray, y: np.ndarray,
                   pinv: np.ndarray | None = None) -> np.ndarray:
    """``y (B, V*C)`` -> ``z (B, G, K)``: the least-squares coefficients of each cluster's block of ``y - mean`` in
    its ``basis_g (K, L)`` rows (padding rows and columns are zero, so they get zero coefficients). ``pinv``:
    ``np.linalg.pinv(basis)`` ``(G, L, K)`` when already computed."""
    g, _, l_max = basis.shape
    r = np.zeros((y.shape[0], g * l_max), np.float64)
    r[:, gather] = y - mean  # every (vertex, coefficient) sits in exactly one cluster slot
    if pinv is None:
        pinv = np.linalg.pinv(basis.astype(np.float64))
    return np.einsum("bgl,glk->bgk", r.reshape(-1, g, l_max), pinv)


def _kind(run: CompareRun) -> str | None:
    """The model kind whose basis the oracle uses: the exported kind, else the run's default."""
    return (run.export_meta or {}).get("model_kind") or run.model_meta.get("default_kind")


@register
class PCAFloor(MethodBase):
    """The truth through the trained model's output PCA (module docstring). Opt-in: ``--methods pca_floor``."""

    name = "pca_floor"
    output = "visibility"
    runtime = "oracle: the baked visibility through the model's output PCA (not a run-time method)"
    default = False

    @classmethod
    def available(cls, run: CompareRun) -> bool:
        kind = _kind(run)  # per-cluster output bases (OutputUnprojection), read from the metadata: no model load
        return bool(kind) and run.run.model_path(kind).is_file() \
            and run.model_meta.get("output_pca", "cluster") == "cluster"

    def prepare(self, run: CompareRun, frames: FrameSet) -> None:
        from prt_torch.models.visibility import load_model

        if frames.baked_visibility is None:
            raise PrtError("pca_floor needs the frames' baked visibility: compare the dataset's held-out frames "
                           "(no --clip)")
        self.kind = _kind(run)
        self.out = load_model(run.run, self.kind).out  # OutputUnprojection: its forward is the expand
        self.basis = self.out.basis.detach().numpy()
        self.gather = self.out.gather.detach().numpy().astype(np.int64)
        self.mean = self.out.mean.detach().numpy()
        self.pinv = np.linalg.pinv(self.basis.astype(np.float64))  # (G, L, K), once
        self.truth = frames.baked_visibility

    def visibility(self, batch: FrameBatch) -> np.ndarray:
        import torch

        y = np.asarray(self.truth[batch.index], np.float64).reshape(len(batch.index), -1)
        z = cluster_reduce(self.basis, self.gather, self.mean, y, self.pinv)
        with torch.no_grad():
            return self.out(torch.from_numpy(z.astype(np.float32))).numpy()

    def info(self) -> dict[str, Any]:
        return {"oracle": True, "model_kind": self.kind}

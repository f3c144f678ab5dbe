"""Parity of an exported ONNX graph with its torch module (onnxruntime vs torch, float32)."""

from __future__ import annotations

import os
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from prt_torch.errors import PrtError

#: default acceptance: max |ort - torch| / max |torch| (the issue asks for <= 1e-4 in float32)
PARITY_RTOL = 1e-4


@dataclass(frozen=True)
class Parity:
    """Result of :func:`check_parity`: the worst relative error over all outputs and its parts."""

    rel_error: float  # max |ort - torch| / max(|torch|)
    max_abs_error: float
    scale: float  # max |torch|

    def as_dict(self) -> dict[str, float]:
        return {"rel_error": self.rel_error, "max_abs_error": self.max_abs_error, "scale": self.scale}


def relative_error(got: np.ndarray, want: np.ndarray) -> Parity:
    """``max |got - want| / max |want|`` (float64 arithmetic)."""
    got = np.asarray(got, dtype=np.float64)
    want = np.asarray(want, dtype=np.float64)
    if got.shape != want.shape:
        raise PrtError(f"parity: output shapes differ, {got.shape} vs {want.shape}")
    scale = float(np.abs(want).max()) if want.size else 0.0
    err = float(np.abs(got - want).max()) if want.size else 0.0
    return Parity(err / max(scale, 1e-30), err, scale)


def check_parity(module, onnx_path: str | os.PathLike[str], inputs: Mapping[str, np.ndarray],
                 rtol: float = PARITY_RTOL, threads: int = 2) -> Parity:
    """Run ``module`` (torch, float32) and the ONNX graph (onnxruntime) on the same ``inputs``.

    ``inputs`` maps graph input names to arrays, in the module's argument order. Raises
    :class:`PrtError` if the relative error exceeds ``rtol``; returns the :class:`Parity`.
    """
    import torch

    from prt_torch.runtime.session import OrtGraph

    graph = OrtGraph(onnx_path, threads=threads)
    feeds = {k: np.ascontiguousarray(v, dtype=np.float32) for k, v in inputs.items()}
    ort_out = graph.run(feeds)
    with torch.no_grad():
        ref = module.eval()(*[torch.from_numpy(feeds[k]) for k in inputs])
    refs = ref if isinstance(ref, (tuple, list)) else (ref,)
    worst: Parity | None = None
    for name, r in zip(graph.outputs, refs, strict=False):
        p = relative_error(ort_out[name], r.detach().numpy())
        if worst is None or p.rel_error > worst.rel_error:
            worst = p
    assert worst is not None
    if worst.rel_error > rtol:
        raise PrtError(f"{os.fspath(onnx_path)}: ONNX/torch parity failed, relative error "
                       f"{worst.rel_error:.3g} > {rtol:g}")
    return worst

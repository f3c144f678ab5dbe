"""``learned_local_linear``, ``learned_local_mlp``: the run's local visibility models (``train.local``,
:mod:`prt_torch.local.models`) on the player's path.

Per frame (timed): the neighbour offsets (numba) (:class:`prt_torch.local.soa.LocalOffsetsSoA`) from the
positions and the compared frames, then the network in onnxruntime: the shipped ``local.onnx`` when it is this
kind's current model (``export.json`` ``local``), else the kind's :class:`~prt_torch.local.models.LocalHead` exported
into the run's compare directory. The frames are the compared frames every method gets (the player computes them
for the shading anyway), so the time is what the local model adds, as the positions-in graphs' time is for the
per-cluster models. ``bytes()``: the graph's initializers plus the neighbour indices.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, ClassVar

import numpy as np

from prt_torch.compare.methods.base import CompareRun, FrameBatch, FrameSet, MethodBase, register
from prt_torch.local.data import neighbour_dtype
from prt_torch.local.soa import offsets_inputs


class LearnedLocal(MethodBase):
    """A trained local kind (``kind``) through onnxruntime."""

    kind: ClassVar[str] = ""
    output = "visibility"

    @classmethod
    def available(cls, run: CompareRun) -> bool:
        return run.run.local_model_path(cls.kind).is_file()

    def prepare(self, run: CompareRun, frames: FrameSet) -> None:
        from prt_torch.export.onnx_file import initializer_bytes
        from prt_torch.local.soa import LocalOffsetsSoA
        from prt_torch.rundir import file_sha256
        from prt_torch.runtime.session import OrtGraph

        mpath = run.run.local_model_path(self.kind)
        shipped = (run.export_meta or {}).get("local")
        if isinstance(shipped, dict) and shipped.get("kind") == self.kind and run.run.local_graph_path.is_file() \
                and shipped.get("model_sha256") == file_sha256(mpath):
            from prt_torch.local.data import load_neighbours

            path, self.source = run.run.local_graph_path, "shipped"
            nb = load_neighbours(run.run)
        else:
            path, nb = self._export(run, mpath)
            self.source = "exported by prt compare"
        self.offsets = LocalOffsetsSoA(nb)
        self.graph = OrtGraph(path, threads=run.threads)
        self.precision = str(self.graph.metadata.get("prt.precision", "fp32"))
        self._bytes = int(initializer_bytes(path) + nb.astype(neighbour_dtype(nb.shape[0])).nbytes)
        self.n_samples = int(nb.shape[1])
        self.runtime = f"numba offsets + onnxruntime ({run.run.relative(path)}, {self.source})"

    def _export(self, run: CompareRun, mpath: Path) -> tuple[Path, np.ndarray]:
        from prt_torch.local.graph import export_head
        from prt_torch.local.models import load_local

        model = load_local(mpath)
        nb = model.neighbours.numpy().astype(np.int32)
        path = run.run.compare_graph_path(f"local_{self.kind}")
        if path.is_file() and path.stat().st_mtime >= mpath.stat().st_mtime:
            return path, nb
        path.parent.mkdir(parents=True, exist_ok=True)
        export_head(model.head, np.zeros((1, 3 * nb.shape[1], nb.shape[0]), np.float32), path,
                    {"prt.model_kind": f"local_{self.kind}"})
        return path, nb

    def visibility(self, batch: FrameBatch) -> np.ndarray:
        p, f = offsets_inputs(batch.positions, batch.frames)
        return self.graph.run_unchecked({"offsets": self.offsets(p, f)})[0]

    def bytes(self) -> int:
        return self._bytes

    def info(self) -> dict[str, Any]:
        return {"kind": f"local_{self.kind}", "graph": self.source, "precision": self.precision,
                "input": "positions+frames", "n_samples": self.n_samples}


@register
class LearnedLocalLinear(LearnedLocal):
    name = "learned_local_linear"
    kind = "linear"


@register
class LearnedLocalMlp(LearnedLocal):
    name = "learned_local_mlp"
    kind = "mlp"

"""``learned_<kind>``: the run's trained visibility models through onnxruntime (one class per kind).

The exported kind runs the shipped ``visibility.onnx`` (what ``prt play`` runs); every other trained kind gets
its :class:`prt_torch.export.graphs.VisibilityGraph` exported into the run's compare directory with the export
package's :func:`prt_torch.export.onnx_file.export_onnx` (re-exported when its model file is newer), so every
learned method is timed on the same run-time path.
"""

from __future__ import annotations

from typing import Any, ClassVar

import numpy as np

from prt_torch.compare.methods import CompareRun, FrameBatch, FrameSet, MethodBase, register


class Learned(MethodBase):
    """A trained kind (``kind``) through onnxruntime."""

    kind: ClassVar[str] = ""
    output = "visibility"

    @classmethod
    def available(cls, run: CompareRun) -> bool:
        return cls.kind in run.model_meta.get("kinds", []) and run.run.model_path(cls.kind).is_file()

    def prepare(self, run: CompareRun, frames: FrameSet) -> None:
        from prt_torch.export.onnx_file import initializer_bytes
        from prt_torch.rundir import file_sha256
        from prt_torch.runtime.session import OrtGraph

        exp = run.export_meta or {}
        shipped = run.run.graph_path("visibility")
        if exp.get("model_kind") == self.kind and shipped.is_file() and \
                exp.get("model_sha256") == file_sha256(run.run.model_path(self.kind)):
            path, self.source = shipped, "shipped"
        else:
            path, self.source = self._export(run), "exported by prt compare"
        self.path = path
        self.graph = OrtGraph(path, threads=run.threads)
        self._bytes = initializer_bytes(path)
        self.runtime = f"onnxruntime ({run.run.relative(path)}, {self.source})"

    def _export(self, run: CompareRun) -> Any:
        import torch

        from prt_torch.export.graphs import VisibilityGraph
        from prt_torch.export.onnx_file import export_onnx

        path = run.run.compare_graph_path(self.kind)
        model_file = run.run.model_path(self.kind)
        if path.is_file() and path.stat().st_mtime >= model_file.stat().st_mtime:
            return path
        path.parent.mkdir(parents=True, exist_ok=True)
        model = run.run.model(self.kind)
        graph = VisibilityGraph(model).eval()
        example = torch.zeros(1, model.n_features)
        export_onnx(graph, [example], path, ("pose",), ("visibility",), {"pose": {0: "B"}, "visibility": {0: "B"}},
                    metadata={"prt.graph": "visibility", "prt.model_kind": self.kind})
        return path

    def visibility(self, batch: FrameBatch) -> np.ndarray:
        return self.graph.run_unchecked({"pose": np.ascontiguousarray(batch.features, dtype=np.float32)})[0]

    def bytes(self) -> int:
        return int(self._bytes)

    def info(self) -> dict[str, Any]:
        return {"kind": self.kind, "graph": self.source}


@register
class LearnedLinear(Learned):
    name = "learned_linear"
    kind = "linear"


@register
class LearnedQuadratic(Learned):
    name = "learned_quadratic"
    kind = "quadratic"


@register
class LearnedMlp(Learned):
    name = "learned_mlp"
    kind = "mlp"

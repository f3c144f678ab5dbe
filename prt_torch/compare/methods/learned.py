"""``learned_<kind>``: the run's trained visibility models through onnxruntime (one class per kind).

The exported kind runs the shipped ``visibility.onnx`` (what ``prt play`` runs); every other trained kind gets
its :class:`prt_torch.export.graphs.VisibilityGraph` exported into the run's compare directory with the export
package's :func:`prt_torch.export.onnx_file.export_onnx` (re-exported when its model file is newer), so every
learned method is timed on the same run-time path.

``learned_<kind>_<precision>`` (``fp32``, ``fp16``, ``int8``; :data:`prt_torch.export.graphs.PRECISIONS`): the
exported kind's visibility graph at the OTHER weight precisions than the shipped one (``learned_<kind>`` is the
shipped graph at the run's precision, ``export.json`` ``precision``), so the accuracy and speed cost of a precision
are rows of the same table.

A DEFORMABLE run (``export.json`` has ``deformable``): every learned method runs the POSITIONS-IN graph (the shipped
``positions.onnx``, or one exported here the same way: the ``input_graph`` of the export shipper of ``deformable``,
:func:`prt_torch.export.shippers.shipper_of`):
positions -> dihedral angles -> model, so its time includes the features, as in ``prt play --sequence``.
"""

from __future__ import annotations

from typing import Any, ClassVar

import numpy as np

from prt_torch.compare.methods.base import CompareRun, FrameBatch, FrameSet, MethodBase, register


class Learned(MethodBase):
    """A trained kind (``kind``) through onnxruntime."""

    kind: ClassVar[str] = ""
    #: the weight precision of the graph (``""``: the shipped graph's, whatever it is)
    precision: ClassVar[str] = ""
    output = "visibility"

    @classmethod
    def available(cls, run: CompareRun) -> bool:
        if not (cls.kind in run.model_meta.get("kinds", []) and run.run.model_path(cls.kind).is_file()):
            return False
        if not cls.precision:
            return True
        exp = run.export_meta or {}  # precision variants: of the exported kind, other than the shipped precision
        return exp.get("model_kind") == cls.kind and exp.get("precision", "fp32") != cls.precision \
            and run.model_meta.get("output_pca", "cluster") == "cluster"  # per-cluster bases: the ones quantised

    def prepare(self, run: CompareRun, frames: FrameSet) -> None:
        from prt_torch.export.onnx_file import initializer_bytes
        from prt_torch.rundir import file_sha256
        from prt_torch.runtime.session import OrtGraph

        exp = run.export_meta or {}
        dfm = exp.get("deformable")
        #: a deformable run's export entry (its positions-in graph is what runs), else None
        self.deform: dict[str, Any] | None = dfm if isinstance(dfm, dict) else None
        shipped = run.run.positions_graph_path if self.deform else run.run.graph_path("visibility")
        self.graph_precision = self.precision or (exp.get("precision", "fp32") if exp.get("model_kind") == self.kind
                                                  else "fp32")
        if not self.precision and exp.get("model_kind") == self.kind and shipped.is_file() and \
                exp.get("model_sha256") == file_sha256(run.run.model_path(self.kind)):
            path, self.source = shipped, "shipped"
        else:
            path, self.source = self._export(run), "exported by prt compare"
        self.path = path
        self.graph = OrtGraph(path, threads=run.threads)
        self._bytes = initializer_bytes(path)
        self.runtime = f"onnxruntime ({run.run.relative(path)}, {self.source}, {self.graph_precision})"

    def _export(self, run: CompareRun) -> Any:
        import torch

        from prt_torch.export.graphs import VisibilityGraph
        from prt_torch.export.onnx_file import export_onnx, read_metadata
        from prt_torch.export.run import lowering

        prec = self.precision or "fp32"
        stem = self.kind if not self.precision else f"{self.kind}_{prec}"
        path = run.run.compare_graph_path(f"{stem}_positions" if self.deform else stem)
        model_file = run.run.model_path(self.kind)
        if path.is_file() and path.stat().st_mtime >= model_file.stat().st_mtime \
                and read_metadata(path).get("prt.precision", "fp32") == prec:
            return path
        path.parent.mkdir(parents=True, exist_ok=True)
        model = run.run.model(self.kind)
        graph = VisibilityGraph(model, precision=prec).eval()
        if self.deform:  # positions -> dihedral angles [+ body features] -> the model, as the export ships it
            from prt_torch.errors import check
            from prt_torch.export.shippers import shipper_of

            build = shipper_of("deformable").input_graph  # the shipper of export.json's deformable entry
            check(build is not None, "the deformable export shipper builds no positions-in graph")
            wrapped = build(run.run, graph, run.character)
            names = wrapped.names
            export_onnx(wrapped.module, list(wrapped.example), path, names, ("visibility",),
                        {k: {0: "B"} for k in (*names, "visibility")},
                        metadata={"prt.graph": "positions", "prt.model_kind": self.kind, "prt.precision": prec},
                        **lowering(prec))
            return path
        example = torch.zeros(1, model.n_features)
        export_onnx(graph, [example], path, ("pose",), ("visibility",), {"pose": {0: "B"}, "visibility": {0: "B"}},
                    metadata={"prt.graph": "visibility", "prt.model_kind": self.kind, "prt.precision": prec},
                    **lowering(prec))
        return path

    def visibility(self, batch: FrameBatch) -> np.ndarray:
        if self.deform:  # the positions-in graph: positions [+ the body features, the pose column's tail]
            feeds = {"positions": np.ascontiguousarray(batch.positions, dtype=np.float32)}
            nb = int(self.deform.get("n_body_features", 0))
            if nb:
                feeds["body"] = np.ascontiguousarray(batch.features[:, -nb:], dtype=np.float32)
            return self.graph.run_unchecked(feeds)[0]
        return self.graph.run_unchecked({"pose": np.ascontiguousarray(batch.features, dtype=np.float32)})[0]

    def bytes(self) -> int:
        return int(self._bytes)

    def info(self) -> dict[str, Any]:
        return {"kind": self.kind, "graph": self.source, "precision": self.graph_precision,
                "input": "positions" if self.deform else "pose"}


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


def _precision_variant(base: type[Learned], precision: str) -> type[Learned]:
    cls = type(f"{base.__name__}{precision.capitalize()}", (base,),
               {"name": f"{base.name}_{precision}", "precision": precision, "__module__": __name__,
                "__doc__": f"{base.name} at {precision} weights (exported by prt compare)."})
    return register(cls)


for _base in (LearnedLinear, LearnedQuadratic, LearnedMlp):
    for _p in ("fp32", "fp16", "int8"):
        _precision_variant(_base, _p)

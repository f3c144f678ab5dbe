"""The run-time data of a DEFORMABLE run (config with ``cloth:``): the frame operator and the positions-in graph.

A deformable run (issue 11) is a normal run whose ``pose`` column is the deformable input features
(:func:`prt_torch.cloth.inputs.cloth_features`: signed dihedral angles of the cloth's interior edges, plus the
body's pose features for the cape) and whose vertex frames come from
:class:`prt_torch.deform.frames.FrameOperator` (no bones). ``prt export`` ships, besides the usual graphs:

* the deform data (``RunDir.deform_path``, ``.npz``, loadable without torch): the frame operator's arrays
  (:meth:`FrameOperator.arrays`, keys prefixed ``op_``), the cloth's interior ``edges (E, 4)`` in subject vertex
  indices, ``cloth_slice (2,)`` (start, stop) and ``n_body_features ()`` (0: no body input);
* the positions-in graph (``RunDir.positions_graph_path``): ``positions (B, V, 3)`` [, ``body (B, Ab)``] ->
  dihedral angles (:func:`position_features_module`, the rule of
  :func:`prt_torch.cloth.inputs.cloth_features`) [concatenated with ``body``] -> the
  model -> ``visibility (B, V, C)`` (original vertex order, the export's precision), checked against torch
  (parity, relative error per precision) and against the dataset: the numpy rule ``cloth_features`` on the held-out
  positions must give the dataset's ``pose`` column, and the frame operator the dataset's baked ``frames``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from prt_torch.cloth.deform_data import write_deform_data
from prt_torch.errors import MissingArtifact, check
from prt_torch.export.shippers import ExportRequest, InputGraph, ShipInputs, Shipment, Shipper
from prt_torch.rundir import RunDir

if TYPE_CHECKING:
    import torch

    from prt_torch.config import RunConfig

#: version of the deformable export (part of the export stage key)
DEFORMABLE_VERSION = 2  # 2: positions_fused.onnx
#: the positions-in graph's inputs (``body`` only when the run appends body features)
POSITIONS_INPUTS = ("positions", "body")
#: worst |numpy cloth_features - dataset pose| (radians) and |FrameOperator frames - baked frames| accepted
FEATURE_ATOL, FRAMES_ATOL = 1e-3, 2e-3


@dataclass
class DeformSpec:
    """What a deformable export needs beyond a skinned one.

    Attributes:
        edges: ``(E, 4)`` int64 interior edges ``(i, j, k, l)`` of the cloth, SUBJECT vertex indices.
        cloth_slice: the cloth's vertex range in the subject.
        n_body_features: body pose features appended after the dihedral angles (0: none).
        operator: the :class:`prt_torch.deform.frames.FrameOperator` of the subject (the bake's frames rule).
    """

    edges: np.ndarray
    cloth_slice: slice
    n_body_features: int
    operator: Any


def run_config(run: RunDir) -> RunConfig | None:
    """The run config recorded by the bake, validated (:meth:`prt_torch.bake.store.BakedDataset.run_config`);
    ``None`` without a dataset or a recorded config."""
    try:
        return run.dataset().run_config()
    except MissingArtifact:
        return None


def deform_spec(run: RunDir) -> DeformSpec:
    """The :class:`DeformSpec` of a deformable run: cloth edges and layout from
    :class:`prt_torch.cloth.subject.ClothSubject` of the recorded config, the frame operator from the character's
    rest mesh and the dataset's cluster labels (:meth:`FrameOperator.from_rest`, the bake's rule)."""
    from prt_torch.cloth.bake import load_subject

    cfg = run_config(run)
    check(cfg is not None and cfg.cloth is not None,
          f"{run.path}: not a deformable run (its recorded config has no cloth: section)")
    subject = load_subject(cfg)
    n_body = 0
    if getattr(cfg.cloth, "append_pose", False):
        n_body = _body_width(run, subject)
    return DeformSpec(edges=np.asarray(subject.cloth_edges, dtype=np.int64), cloth_slice=subject.cloth_slice,
                      n_body_features=n_body, operator=frame_operator(run))


def _body_width(run: RunDir, subject: Any) -> int:
    """Body features appended to the dihedral angles: the dataset's feature width minus the edge count."""
    width = int(run.dataset().pose.shape[1])
    n_edges = int(np.asarray(subject.cloth_edges).shape[0])
    check(width >= n_edges, f"{run.dataset_path}: pose has {width} columns, fewer than the cloth's {n_edges} edges")
    return width - n_edges


def frame_operator(run: RunDir) -> Any:
    """:class:`FrameOperator` of the run's subject (:func:`prt_torch.bake.deformable.frame_operator`: rest mesh of
    ``character.npz``, the dataset's cluster labels - the bake's rule)."""
    from prt_torch.bake.deformable import frame_operator as subject_operator

    return subject_operator(run.character(), np.asarray(run.dataset().cluster))


# -- the positions-in graph -----------------------------------------------------------------------------------
def position_features_module(edges: np.ndarray, n_body_features: int) -> torch.nn.Module:
    """``positions (B, V, 3)`` [, ``body (B, Ab)``] -> ``(B, E [+ Ab])``: the torch twin of the numpy input rule
    :func:`prt_torch.cloth.inputs.cloth_features` (the dihedral angles,
    :class:`prt_torch.deform.dihedral_torch.DihedralAngles`, then the body features appended)."""
    import torch

    from prt_torch.deform.dihedral_torch import DihedralAngles

    class PositionFeatures(torch.nn.Module):
        def __init__(self) -> None:
            super().__init__()
            self.dihedral = DihedralAngles(np.asarray(edges))
            self.n_body = int(n_body_features)

        def forward(self, positions: torch.Tensor, body: torch.Tensor | None = None) -> torch.Tensor:
            f = self.dihedral(positions)
            return f if body is None else torch.cat([f, body], dim=-1)

    return PositionFeatures().eval()


def positions_graph_module(vis_graph: Any, edges: np.ndarray, n_body_features: int) -> torch.nn.Module:
    """``positions (B, V, 3)`` [, ``body (B, Ab)``] -> ``visibility (B, V, C)``: the input features
    (:func:`position_features_module`) fed to ``vis_graph`` (a :class:`VisibilityGraph`)."""
    import torch

    class PositionsGraph(torch.nn.Module):
        def __init__(self) -> None:
            super().__init__()
            self.features = position_features_module(edges, n_body_features)
            self.vis = vis_graph

        def forward(self, positions: torch.Tensor, body: torch.Tensor | None = None) -> torch.Tensor:
            return self.vis(self.features(positions, body))

    return PositionsGraph().eval()


def positions_fused_module(fused_graph: Any, edges: np.ndarray, n_body_features: int) -> torch.nn.Module:
    """``positions (B, V, 3)`` [, ``body``], then the shading inputs of
    :data:`prt_torch.export.graphs.FUSED_INPUTS` (frames, view dirs in ``fused_graph``'s vertex order, lobes, RPO)
    -> ``radiance (B, V, 3)`` (that order): the input features (:func:`position_features_module`) fed to
    ``fused_graph`` (a :class:`~prt_torch.export.graphs.FusedGraph`, cluster-sorted like the skinned export's fused
    graph)."""
    import torch

    class PositionsFused(torch.nn.Module):
        def __init__(self) -> None:
            super().__init__()
            self.features = position_features_module(edges, n_body_features)
            self.fused = fused_graph

        def forward(self, positions: torch.Tensor, *rest: torch.Tensor) -> torch.Tensor:
            if self.features.n_body:
                return self.fused(self.features(positions, rest[0]), *rest[1:])
            return self.fused(self.features(positions), *rest)

    return PositionsFused().eval()


def graph_input_names(n_body_features: int) -> tuple[str, ...]:
    """The positions-in graph's input names for a run with ``n_body_features`` body features."""
    return POSITIONS_INPUTS if n_body_features > 0 else POSITIONS_INPUTS[:1]


def ship_deformable(run: RunDir, spec: DeformSpec, vis_graph: Any, held: dict[str, np.ndarray],
                    base_meta: dict[str, Any], rtol: float, opset: int = 17, exporter: str = "torchscript",
                    lowered: dict[str, str | None] | None = None, fused_graph: Any = None,
                    fused_inputs: dict[str, np.ndarray] | None = None) -> dict[str, Any]:
    """Write the deform data and the positions-in graph of a deformable run; check them. Returns the
    ``export.json`` ``deformable`` entry.

    ``held``: held-out ``pose (F, A)``, ``frames (F, V, 3, 3)``, ``positions (F, V, 3)`` of the dataset
    (:func:`prt_torch.export.run.heldout_inputs`); ``vis_graph``: the exported :class:`VisibilityGraph`;
    ``fused_graph`` / ``fused_inputs``: the export's :class:`FusedGraph` and its parity inputs (``pose`` and the
    shading inputs, vertex axes in its order) - given, the positions-in radiance graph is shipped too.
    Raises :class:`PrtError` when the numpy feature rule does not give the dataset's ``pose`` column, the frame
    operator does not give its baked ``frames``, or ONNX/torch parity fails.
    """
    import torch

    from prt_torch.cloth.inputs import cloth_features
    from prt_torch.export.onnx_file import export_onnx, initializer_bytes
    from prt_torch.export.parity import check_parity

    pos, pose, frames = held["positions"], held["pose"], held["frames"]
    V = pos.shape[1]
    nb = int(spec.n_body_features)
    edges = np.asarray(spec.edges, dtype=np.int64)
    check(edges.ndim == 2 and edges.shape[1] == 4 and edges.size > 0 and int(edges.max()) < V and int(edges.min()) >= 0,
          f"cloth edges must be (E, 4) subject vertex indices < {V}, got shape {edges.shape}")
    check(pose.shape[1] == edges.shape[0] + nb, f"the model takes {pose.shape[1]} features but the cloth has "
                                                f"{edges.shape[0]} interior edges + {nb} body features")
    body = np.ascontiguousarray(pose[:, pose.shape[1] - nb:]) if nb else None
    feats = np.asarray(cloth_features(pos, edges, body), dtype=np.float32)
    feat_err = float(np.abs(feats - pose).max())
    check(feat_err <= FEATURE_ATOL, f"{run.path}: cloth_features of the held-out positions differ from the "
                                    f"dataset's pose column by {feat_err:.3g} (> {FEATURE_ATOL}): re-bake the run")
    op_frames = np.asarray(spec.operator.frames(pos), dtype=np.float32)
    frames_err = float(np.abs(op_frames - frames).max())
    check(frames_err <= FRAMES_ATOL, f"{run.path}: the frame operator's frames differ from the baked frames by "
                                     f"{frames_err:.3g} (> {FRAMES_ATOL}): re-bake the run")
    write_deform_data(run, spec)

    module = positions_graph_module(vis_graph, edges, nb)
    names = graph_input_names(nb)
    inputs = {"positions": np.ascontiguousarray(pos, dtype=np.float32)}
    if nb:
        inputs["body"] = body
    batch = {0: "B"}
    path = run.positions_graph_path
    args = [torch.from_numpy(inputs[k]) for k in names]
    meta = {**base_meta, "prt.graph": "positions", "prt.vertex_order": "original",
            "prt.n_edges": int(edges.shape[0]), "prt.n_body_features": nb,
            "prt.positions": "positions input (B, V, 3) world, subject vertices (body then cloth for the cape)"}
    export_onnx(module, args, path, names, ("visibility",), {**{k: batch for k in names}, "visibility": batch},
                metadata=meta, opset=opset, exporter=exporter, **(lowered or {}))
    from prt_torch.export.graphs import set_int8_emulation

    set_int8_emulation(module, True)
    try:
        p = check_parity(module, path, inputs, rtol=rtol)
    finally:
        set_int8_emulation(module, False)
    fused: dict[str, Any] = {}
    if fused_graph is not None and fused_inputs is not None:
        from prt_torch.export.graphs import FUSED_INPUTS

        fmod = positions_fused_module(fused_graph, edges, nb)
        fnames = (*names, *FUSED_INPUTS[1:])
        finputs = {**inputs, **{k: fused_inputs[k] for k in FUSED_INPUTS[1:]}}
        fpath = run.positions_fused_path
        dyn = {k: batch for k in (*names, "frames", "view_dirs", "radiance")}
        export_onnx(fmod, [torch.from_numpy(np.ascontiguousarray(finputs[k], dtype=np.float32)) for k in fnames],
                    fpath, fnames, ("radiance",), dyn, metadata={**meta, "prt.graph": "positions_fused",
                                                                 "prt.vertex_order": "cluster"
                                                                 if fused_graph.vertex_order is not None
                                                                 else "original"},
                    opset=opset, exporter=exporter, **(lowered or {}))
        set_int8_emulation(fmod, True)
        try:
            fp = check_parity(fmod, fpath, finputs, rtol=rtol)
        finally:
            set_int8_emulation(fmod, False)
        fused = {"fused_file": run.relative(fpath), "fused_inputs": list(fnames),
                 "fused_parity": {**fp.as_dict(), "file_bytes": fpath.stat().st_size}}
    return {**fused,"version": DEFORMABLE_VERSION, "deform_file": run.relative(run.deform_path),
            "positions_file": run.relative(path), "inputs": list(names), "n_edges": int(edges.shape[0]),
            "n_body_features": nb, "cloth_slice": [int(spec.cloth_slice.start or 0), int(spec.cloth_slice.stop)],
            "features_max_error": feat_err, "frames_max_error": frames_err,
            "parity": {**p.as_dict(), "initializer_bytes": initializer_bytes(path), "file_bytes": path.stat().st_size}}


# -- the export stage's hook (prt_torch.export.shippers.SHIPPERS) ----------------------------------------------
def plan_stage(request: ExportRequest) -> Shipment:
    """The export plan of a deformable run (nothing for the others): the deform data and the two positions-in
    graphs; the spec is the caller's (``export_run(deform=)``) or :func:`deform_spec` of the run; the key records
    :data:`DEFORMABLE_VERSION` and the body feature count."""
    if not request.deformable:
        return Shipment()
    run = request.run
    spec = request.deform if request.deform is not None else deform_spec(run)
    return Shipment(files=(run.deform_path, run.positions_graph_path, run.positions_fused_path),
                    key={"deformable": [DEFORMABLE_VERSION, spec.n_body_features]}, state=spec)


def ship_stage(shipment: Shipment, inputs: ShipInputs) -> dict[str, Any] | None:
    """:func:`ship_deformable` with the export's graphs and held-out frames: ``export.json``'s ``deformable``
    entry (``None`` for a skinned run)."""
    if shipment.state is None:
        return None
    out = ship_deformable(inputs.run, shipment.state, inputs.vis_graph, inputs.held, inputs.base_meta, inputs.rtol,
                          opset=inputs.opset, exporter=inputs.exporter, lowered=dict(inputs.lowered),
                          fused_graph=inputs.fused_graph, fused_inputs=inputs.fused_inputs)
    inputs.log(f"  {inputs.run.positions_graph_path.name}: parity rel. error {out['parity']['rel_error']:.2e} "
               f"(positions -> dihedral angles -> visibility)")
    return out


def input_graph(run: RunDir, vis_graph: Any, character: Any) -> InputGraph:
    """The positions-in graph around another visibility graph, as the export ships it: from the run's deform data
    (:class:`prt_torch.cloth.deform_data.DeformData`: edges, body feature count), example inputs the rest
    vertices of ``character`` and zero body features."""
    import torch

    from prt_torch.cloth.deform_data import DeformData

    d = DeformData.load(run.deform_path)
    names = graph_input_names(d.n_body_features)
    rest = torch.as_tensor(np.asarray(character.rest_vertices, np.float32))[None]
    example = (rest, torch.zeros(1, d.n_body_features))[:len(names)]
    return InputGraph(module=positions_graph_module(vis_graph, d.edges, d.n_body_features), names=names,
                      example=example)


#: ``prt export``'s deformable part (:data:`prt_torch.export.shippers.SHIPPERS`)
SHIPPER = Shipper(name="deformable", plan=plan_stage, ship=ship_stage, input_graph=input_graph)

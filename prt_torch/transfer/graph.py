"""The learned transfer graph (seed 000): ``pose -> transfer [, subsurface] -> L . t`` for onnxruntime.

Graph (:func:`transfer_graph`, written by :func:`write_transfer_graph`): inputs ``pose (B, A)`` and the world-frame
SH lighting ``light (n_light, 3)``; outputs ``transfer (B, V, C6)`` and its unit-albedo shading ``radiance = L . t
(B, V, 3)`` (:func:`prt_torch.shade.diffuse.shade_diffuse_prt`, the first ``min(C6, n_light)`` coefficients), and,
when the run learned the subsurface array too, ``subsurface (B, V, C6)`` and ``subsurface_radiance = L . t_sss``.
The models are the run's ``models/<array>_<kind>.pt`` (:mod:`prt_torch.transfer.fit`) as exported
(:class:`prt_torch.export.graphs.VisibilityGraph`, float32). ``prt export`` ships it as the run's transfer graph
(:meth:`prt_torch.rundir.RunDir.transfer_graph_path`, parity-checked against torch, in ``export.json``
``transfer``); ``prt compare``'s ``learned_transfer`` runs that file, or writes the same graph into its compare
directory for a run exported before it (or another kind); the player (``prt play --renderer transfer``) fetches
only the radiance outputs. The dot product is in the graph: against ``transfer`` out + numpy ``L . t`` it was
1.13x faster per call (order 4, 1430 vertices, transfer + subsurface, one thread): the ``(V, C6)`` arrays never
leave onnxruntime.

Shading rule: :func:`prt_torch.transfer.shading.transfer_shading` (one function for compare and the
player).

torch only inside the graph-building functions.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from prt_torch.errors import check
from prt_torch.export.shippers import ExportRequest, ShipInputs, Shipment, Shipper
from prt_torch.transfer.shading import ARRAYS, graph_outputs

#: bumped when the graph's inputs / outputs change (part of ``prt export``'s stage key)
TRANSFER_GRAPH_VERSION = 1


def transfer_graph(models: dict[str, Any], n_light: int) -> Any:
    """``(pose (B, A), light (n_light, 3)) -> (t, L . t)`` per array of ``models {array: VisibilityModel}`` (in
    :data:`ARRAYS` order), one torch module for export."""
    import torch

    from prt_torch.export.graphs import VisibilityGraph
    from prt_torch.shade.diffuse import shade_diffuse_prt

    arrays = [a for a in ARRAYS if a in models]
    check(bool(arrays) and "transfer" in arrays, f"a transfer graph needs the transfer model, got {sorted(models)}")
    check(int(n_light) >= 1, f"n_light must be >= 1, got {n_light}")

    class TransferGraph(torch.nn.Module):
        def __init__(self) -> None:
            super().__init__()
            self.nets = torch.nn.ModuleList([VisibilityGraph(models[a]) for a in arrays])
            self.cs = [min(int(models[a].n_coeffs), int(n_light)) for a in arrays]

        def forward(self, pose: torch.Tensor, light: torch.Tensor) -> tuple[torch.Tensor, ...]:
            out: list[torch.Tensor] = []
            for net, c in zip(self.nets, self.cs, strict=True):
                t = net(pose)
                out += [t, shade_diffuse_prt(t[..., :c], light[:c], check=False)]
            return tuple(out)

    return TransferGraph().eval()


def load_models(run: Any, kind: str, arrays: tuple[str, ...] | list[str]) -> dict[str, Any]:
    """``{array: VisibilityModel}`` of the run's ``models/<array>_<kind>.pt`` (verified by ``transfer.json``)."""
    from prt_torch.models import load_model_file

    return {a: load_model_file(run.transfer_model_path(kind, a)) for a in arrays}


def write_transfer_graph(models: dict[str, Any], n_light: int, path: Path, metadata: dict[str, Any],
                         pose: np.ndarray | None = None, opset: int = 17, exporter: str = "torchscript",
                         rtol: float = 1e-4) -> dict[str, Any]:
    """Export :func:`transfer_graph` to ``path`` (atomically) and check onnxruntime against torch on ``pose``
    (``None``: no parity check). Returns ``{"parity": ..., "outputs": [...]}``."""
    import torch

    from prt_torch.export.onnx_file import export_onnx

    graph = transfer_graph(models, n_light)
    arrays = [a for a in ARRAYS if a in models]
    outs = graph_outputs(arrays)
    n_feat = int(models["transfer"].n_features)
    for a in arrays:
        check(int(models[a].n_features) == n_feat and int(models[a].n_vertices) == int(models["transfer"].n_vertices),
              f"the {a} model's inputs/vertices differ from the transfer model's")
    example = pose if pose is not None else np.zeros((1, n_feat), np.float32)
    light = np.random.default_rng(0).normal(size=(int(n_light), 3)).astype(np.float32)
    path.parent.mkdir(parents=True, exist_ok=True)
    export_onnx(graph, [torch.from_numpy(np.ascontiguousarray(example, np.float32)), torch.from_numpy(light)],
                path, ("pose", "light"), outs, {"pose": {0: "B"}, **{o: {0: "B"} for o in outs}},
                metadata={**metadata, "prt.graph": "transfer", "prt.arrays": ",".join(arrays),
                          "prt.n_light": str(int(n_light)), "prt.precision": "fp32"},
                opset=opset, exporter=exporter)
    parity = None
    if pose is not None:
        from prt_torch.export.parity import check_parity

        parity = check_parity(graph, path, {"pose": example, "light": light}, rtol=rtol).as_dict()
    return {"parity": parity, "outputs": list(outs), "arrays": arrays}


def ship_transfer(run: Any, n_light: int, pose: np.ndarray, base_meta: dict[str, Any], opset: int = 17,
                  exporter: str = "torchscript", rtol: float = 1e-4) -> dict[str, Any] | None:
    """``prt export``'s step: the run's transfer graph (default kind, every learned array) when the run has a
    verified ``transfer.json``, else None (and a stale graph file is removed). Returns ``export.json``'s
    ``transfer`` entry: file, kind, arrays, outputs, ``n_light``, parity, the bake's subsurface parameters."""
    from prt_torch.export.onnx_file import initializer_bytes
    from prt_torch.rundir import file_sha256

    path = run.transfer_graph_path
    if not run.transfer_json.is_file():
        path.unlink(missing_ok=True)
        return None
    meta = run.transfer_meta()  # verified: a damaged record is a one-line error, not a silent skip
    kind = str(meta["default_kind"])
    arrays = [a for a in ARRAYS if a in meta.get("arrays", {})]
    check("transfer" in arrays, f"{run.transfer_json}: no learned transfer array")
    models = load_models(run, kind, arrays)
    check(int(models["transfer"].n_features) == int(pose.shape[1]),
          f"the transfer model takes {models['transfer'].n_features} pose features, the dataset gives {pose.shape[1]}")
    res = write_transfer_graph(models, n_light, path, {**base_meta, "prt.model_kind": kind}, pose=pose,
                               opset=opset, exporter=exporter, rtol=rtol)
    params = (meta.get("bake") or {}).get("subsurface") if "subsurface" in arrays else None
    return {"file": run.relative(path), "kind": kind, "arrays": res["arrays"], "outputs": res["outputs"],
            "inputs": ["pose", "light"], "n_light": int(n_light), "n_coeffs": int(models["transfer"].n_coeffs),
            "parity": {**res["parity"], "initializer_bytes": initializer_bytes(path),
                       "file_bytes": path.stat().st_size},
            "subsurface": params, "transfer_json_sha256": file_sha256(run.transfer_json),
            "shading": "albedo * (L . t) + albedo / mean(albedo) * (L . t_sss)",
            "version": TRANSFER_GRAPH_VERSION}


def plan_stage(request: ExportRequest) -> Shipment:
    """The export plan: the transfer graph when the run has a ``transfer.json``; the key records its sha256 (it
    records the models') and :data:`TRANSFER_GRAPH_VERSION` (no part without one: the keys of runs exported
    before the graph existed stay valid)."""
    run = request.run
    if not run.transfer_json.is_file():
        return Shipment()
    from prt_torch.rundir import file_sha256

    return Shipment(files=(run.transfer_graph_path,),
                    key={"transfer": [file_sha256(run.transfer_json), TRANSFER_GRAPH_VERSION]})


def ship_stage(shipment: Shipment, inputs: ShipInputs) -> dict[str, Any] | None:
    """:func:`ship_transfer` on the held-out poses (``n_light`` = the model's coefficient count): ``export.json``'s
    ``transfer`` entry, ``None`` (a stale graph removed) without ``transfer.json``."""
    run = inputs.run
    transfer = ship_transfer(run, inputs.order * inputs.order, inputs.held["pose"], inputs.base_meta,
                             opset=inputs.opset, exporter=inputs.exporter)
    if transfer is not None:
        inputs.log(f"  {run.transfer_graph_path.name}: parity rel. error {transfer['parity']['rel_error']:.2e}")
    return transfer


#: ``prt export``'s learned transfer graph, seed 000 (:data:`prt_torch.export.shippers.SHIPPERS`)
SHIPPER = Shipper(name="transfer", plan=plan_stage, ship=ship_stage)

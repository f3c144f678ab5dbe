"""The shipped local visibility network of a deformable run (``train.local.default``; :mod:`prt_torch.local.models`).

``prt export`` writes, when the run's training config names a local kind to ship:

* ``local.npz`` (:attr:`RunDir.local_data_path`): ``neighbours (V, S)``, the model's neighbour indices (int16 up to
  32,767 vertices, else int32);
* ``local.onnx`` (:attr:`RunDir.local_graph_path`): the network only, ``offsets (B, 3 S, V) -> visibility
  (B, V, C)`` (:class:`prt_torch.local.models.LocalHead`). The player computes ``offsets`` with the run-time twin
  :class:`prt_torch.local.soa.LocalOffsetsSoA` from the positions and the frames it computes anyway
  (numba; onnxruntime's Gather of the neighbour coordinates is ~10x slower); its per-vertex tables
  (the first-layer term and the intercepts, most of its bytes) are stored in float16 when the fit put them on the
  float16 grid (:func:`table_lowering`), exactly.

Checked at export: the run-time twin against the torch rule :func:`prt_torch.local.models.local_offsets` on held-out
frames, and onnxruntime against torch (parity).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from prt_torch.errors import check
from prt_torch.export.shippers import ExportRequest, ShipInputs, Shipment, Shipper
from prt_torch.rundir import RunDir

#: version of the shipped local graph (part of the export key when one ships)
LOCAL_GRAPH_VERSION = 1
#: worst |run-time twin - torch rule| accepted, relative to the largest offset
TWIN_RTOL = 1e-5


def shipped_local_kind(run: RunDir) -> str | None:
    """The local kind the run ships (``train.local.default`` of its model metadata), or ``None``."""
    cfg = run.model_meta().get("train_config", {}).get("local")
    kind = cfg.get("default") if isinstance(cfg, dict) else None
    if kind is not None:
        check(run.local_model_path(kind).is_file(), f"{run.path}: train.local.default is {kind!r} but "
                                                    f"{run.relative(run.local_model_path(kind))} is missing: "
                                                    f"run `prt train` again")
    return kind


#: the per-vertex tables of a LocalHead (ONNX initializer names), stored in float16 when they are on its grid
FP16_TABLES = r"(^|\.)(b0|mean)$"


def table_lowering(head: Any) -> dict[str, str | None]:
    """``export_onnx`` keywords of a :class:`~prt_torch.local.models.LocalHead`: its per-vertex tables in float16
    when every value is a float16 value (fits round them: :func:`prt_torch.local.fit.to_fp16_grid`), else none
    (parity would break)."""
    import torch

    tables = [t for t in (getattr(head, "b0", None), head.mean) if t is not None]
    exact = all(torch.equal(t, t.to(torch.float16).to(torch.float32)) for t in tables)
    return {"fp16_weights": FP16_TABLES if exact else None}


def export_head(head: Any, offsets: np.ndarray, path: Any, metadata: dict[str, Any], opset: int = 17,
                exporter: str = "torchscript") -> bool:
    """Export a :class:`~prt_torch.local.models.LocalHead` to ``path`` (``offsets (B, 3 S, V) -> visibility``, batch
    axis dynamic, ``offsets`` the example input), its per-vertex tables in float16 when they are exact
    (:func:`table_lowering`). Returns whether they are."""
    import torch

    from prt_torch.export.onnx_file import export_onnx

    low = table_lowering(head)
    fp16 = low["fp16_weights"] is not None
    meta = {**metadata, "prt.graph": "local", "prt.precision": "fp32 (per-vertex tables fp16)" if fp16 else "fp32"}
    export_onnx(head, [torch.from_numpy(np.ascontiguousarray(offsets, np.float32))], path, ("offsets",),
                ("visibility",), {"offsets": {0: "B"}, "visibility": {0: "B"}}, metadata=meta, opset=opset,
                exporter=exporter, **low)
    return fp16


def ship_local(run: RunDir, kind: str, held: dict[str, np.ndarray], base_meta: dict[str, Any], rtol: float,
               opset: int = 17, exporter: str = "torchscript") -> dict[str, Any]:
    """Write ``local.npz`` and ``local.onnx`` for the run's local ``kind``; check the run-time twin and the parity on
    ``held`` (``positions (F, V, 3)``, ``frames (F, V, 3, 3)``). Returns the ``export.json`` ``local`` entry."""
    import torch

    from prt_torch.export.onnx_file import initializer_bytes
    from prt_torch.export.parity import check_parity
    from prt_torch.local.data import write_neighbours
    from prt_torch.local.models import load_local, local_offsets
    from prt_torch.local.soa import LocalOffsetsSoA, offsets_inputs
    from prt_torch.rundir import file_sha256

    mpath = run.local_model_path(kind)
    model = load_local(mpath)
    nb = model.neighbours.numpy().astype(np.int32)
    pos, frames = held["positions"], held["frames"]
    check(pos.shape[1] == model.n_vertices, f"{mpath}: {model.n_vertices} vertices, the run's frames {pos.shape[1]}")
    p_soa, f_soa = offsets_inputs(pos, frames)
    x = LocalOffsetsSoA(nb)(p_soa, f_soa)
    with torch.no_grad():
        ref = local_offsets(torch.from_numpy(np.asarray(pos, np.float32)), torch.from_numpy(np.asarray(frames,
                                                                                                      np.float32)),
                            model.neighbours).transpose(1, 2).numpy()
    twin_err = float(np.abs(x - ref).max() / max(float(np.abs(ref).max()), 1e-30))
    check(twin_err <= TWIN_RTOL, f"{run.path}: the run-time local offsets differ from the torch rule by {twin_err:.3g} "
                                 f"(> {TWIN_RTOL})")
    nb_bytes = write_neighbours(run, nb)
    path = run.local_graph_path
    meta = {**base_meta, "prt.model_kind": f"local_{kind}", "prt.vertex_order": "original",
            "prt.model_sha256": file_sha256(mpath),
            "prt.offsets": "offsets input (B, 3 S, V): row k S + s = frame row k (t, b, n) . (p_neighbour_s - p), "
                           f"neighbours in {run.local_data_path.name}"}
    fp16 = export_head(model.head, x, path, meta, opset=opset, exporter=exporter)
    p = check_parity(model.head, path, {"offsets": x}, rtol=rtol)
    return {"version": LOCAL_GRAPH_VERSION, "kind": kind, "file": run.relative(path),
            "data_file": run.relative(run.local_data_path), "model_file": run.relative(mpath),
            "model_sha256": file_sha256(mpath), "n_samples": int(nb.shape[1]), "inputs": ["offsets"],
            "twin_max_rel_error": twin_err,
            "bytes": int(initializer_bytes(path) + nb_bytes),
            "tables": "fp16" if fp16 else "fp32",
            "parity": {**p.as_dict(), "initializer_bytes": initializer_bytes(path), "file_bytes": path.stat().st_size}}


def plan_stage(request: ExportRequest) -> Shipment:
    """The export plan: ``local.onnx`` and ``local.npz`` when a deformable run ships a local kind
    (:func:`shipped_local_kind`); the key records :data:`LOCAL_GRAPH_VERSION`, the kind and its model's sha256."""
    run = request.run
    kind = shipped_local_kind(run) if request.deformable else None
    if kind is None:
        return Shipment()
    from prt_torch.rundir import file_sha256

    return Shipment(files=(run.local_graph_path, run.local_data_path),
                    key={"local": [LOCAL_GRAPH_VERSION, kind, file_sha256(run.local_model_path(kind))]}, state=kind)


def ship_stage(shipment: Shipment, inputs: ShipInputs) -> dict[str, Any] | None:
    """:func:`ship_local` (float32 parity tolerance) of the plan's kind: ``export.json``'s ``local`` entry; without
    one, ``None`` and the files an earlier export shipped are removed."""
    run, kind = inputs.run, shipment.state
    if kind is None:
        run.local_graph_path.unlink(missing_ok=True)
        run.local_data_path.unlink(missing_ok=True)
        return None
    from prt_torch.export.run import PARITY_RTOL_BY_PRECISION

    local = ship_local(run, kind, inputs.held, inputs.base_meta, PARITY_RTOL_BY_PRECISION["fp32"],
                       opset=inputs.opset, exporter=inputs.exporter)
    inputs.log(f"  {run.local_graph_path.name}: parity rel. error {local['parity']['rel_error']:.2e} "
               f"(local {kind}: neighbour offsets -> visibility)")
    return local


#: ``prt export``'s local visibility network, the player runs it instead of the per-cluster model
#: (:data:`prt_torch.export.shippers.SHIPPERS`)
SHIPPER = Shipper(name="local", plan=plan_stage, ship=ship_stage)

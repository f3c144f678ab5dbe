"""The SHEXP sphere-blocker visibility graph: :class:`prt_torch.shexp.ShexpVisibility` as ONNX.

Inputs ``points (B, V, 3)``, ``frames (B, V, 3, 3)`` (rows t, b, n), ``centers (B, S, 3)``, ``radii (B, S)``;
output ``visibility (B, V, C)`` local-frame SH, float32. ``B``, ``V`` and ``S`` are dynamic axes. HYB's
squaring steps are an ONNX ``Loop`` of the batch's largest count (each element keeps its value after its own).
Metadata: ``kind=shexp``, ``order``, ``method``, ``below_horizon`` (``none`` for the whole sphere),
``prt.shexp_version`` (:data:`SHEXP_GRAPH_VERSION`).
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import torch

from prt_torch.errors import MissingArtifact
from prt_torch.export.onnx_file import export_onnx
from prt_torch.export.parity import PARITY_RTOL, Parity, check_parity
from prt_torch.export.shippers import ExportRequest, ShipInputs, Shipment, Shipper
from prt_torch.rundir import RunDir
from prt_torch.scene.shexp_kernel import ShexpTables
from prt_torch.shexp.visibility import ShexpVisibility

SHEXP_GRAPH_VERSION = 3
"""Metadata ``prt.shexp_version`` of graphs written by this code. 3: the tables also in the metadata
(``prt_torch.scene.shexp_kernel.TABLES_METADATA_KEY``, read by the compiled scene pass). 2: cos-uniform log table,
zonal sum without ``(V, S, C)`` tensors, squaring through point values in an ONNX ``Loop`` of ``max(k)`` steps (~10x
faster than 1, same inputs, outputs and numerics to ~1e-3). Consumers may re-export an older graph (``prt compare``
does)."""
SHEXP_INPUTS = ("points", "frames", "centers", "radii")
SHEXP_OUTPUTS = ("visibility",)
SHEXP_PARITY_RTOL = 1e-3
"""ORT vs torch acceptance for this graph: max abs error / max |v|. Looser than the MLP graphs'
:data:`PARITY_RTOL` because HYB's squaring steps amplify float32 rounding differences (measured ~1e-5)."""


def example_inputs(n_vertices: int = 5, n_spheres: int = 3, batch: int = 1, seed: int = 0) -> dict[str, np.ndarray]:
    """Random but valid inputs (receivers near, sometimes inside, the spheres), for tracing and parity."""
    rng = np.random.default_rng(seed)
    pts = rng.normal(size=(batch, n_vertices, 3)).astype(np.float32)
    q, _ = np.linalg.qr(rng.normal(size=(batch, n_vertices, 3, 3)))
    frames = np.swapaxes(q, -1, -2).astype(np.float32)
    frames *= np.sign(np.linalg.det(frames))[..., None, None]  # proper rotations (rows t, b, n)
    centers = rng.normal(size=(batch, n_spheres, 3)).astype(np.float32) * 1.5
    radii = rng.uniform(0.2, 0.8, size=(batch, n_spheres)).astype(np.float32)
    return {"points": pts, "frames": frames.astype(np.float32), "centers": centers, "radii": radii}


def export_shexp(path: str | os.PathLike[str], order: int, method: str = "hyb", below_horizon: str | None = None,
                 metadata: dict[str, str] | None = None) -> Path:
    """Write the SHEXP graph to ``path`` atomically (``torch.onnx.export`` via :func:`export_onnx`)."""
    module = ShexpVisibility(order, method, below_horizon)
    ex = example_inputs()
    meta = {"kind": "shexp", "order": str(order), "method": method,
            "below_horizon": "none" if below_horizon is None else below_horizon,
            "prt.shexp_version": str(SHEXP_GRAPH_VERSION)}
    if method == "hyb":  # the compiled scene pass reads the graph's tables from its metadata (no onnx, no torch)
        b = {k: v.detach().cpu().numpy() for k, v in module.named_buffers()}
        meta.update(ShexpTables(order, b["table"], b["exp.ol"], b["exp.to_points"], b["exp.from_points"]).to_metadata())
    meta.update(metadata or {})
    return export_onnx(module, [torch.from_numpy(ex[k]) for k in SHEXP_INPUTS], path, SHEXP_INPUTS, SHEXP_OUTPUTS,
                       dynamic_axes={"points": {0: "B", 1: "V"}, "frames": {0: "B", 1: "V"},
                                     "centers": {0: "B", 1: "S"}, "radii": {0: "B", 1: "S"},
                                     "visibility": {0: "B", 1: "V"}},
                       metadata=meta)


def shexp_parity(path: str | os.PathLike[str], order: int, method: str = "hyb", below_horizon: str | None = None,
                 inputs: dict[str, np.ndarray] | None = None, rtol: float = SHEXP_PARITY_RTOL) -> Parity:
    """onnxruntime vs torch on ``inputs`` (default: fresh example inputs of another size than the trace)."""
    ex = inputs if inputs is not None else example_inputs(n_vertices=64, n_spheres=7, batch=2, seed=1)
    return check_parity(ShexpVisibility(order, method, below_horizon), path, {k: ex[k] for k in SHEXP_INPUTS},
                        rtol=rtol)


def is_current(path: str | os.PathLike[str]) -> bool:
    """Whether the SHEXP graph at ``path`` was written by this code's graph version (:data:`SHEXP_GRAPH_VERSION`)."""
    from prt_torch.export.onnx_file import read_metadata

    return read_metadata(path).get("prt.shexp_version") == str(SHEXP_GRAPH_VERSION)


__all__ = ["PARITY_RTOL", "SHEXP_GRAPH_VERSION", "SHEXP_INPUTS", "SHEXP_OUTPUTS", "blocker_count", "example_inputs",
           "export_shexp", "is_current", "ship_shexp", "shexp_parity"]


def blocker_count(run: RunDir | Mapping[str, Any]) -> int:
    """The run's sphere count: the bake config's ``blockers`` (recorded in the dataset's ``config`` attrs, read
    validated by :func:`prt_torch.bake.store.recorded_bake_config`; ``run`` is the run directory or those attrs),
    :data:`prt_torch.blockers.spheres.DEFAULT_SPHERES` for datasets baked before the field existed."""
    from prt_torch.bake.store import recorded_bake_config
    from prt_torch.blockers.spheres import DEFAULT_SPHERES

    if isinstance(run, RunDir):
        try:
            attrs: Mapping[str, Any] = run.dataset().attrs
        except MissingArtifact:
            return DEFAULT_SPHERES
    else:
        attrs = run
    cfg = recorded_bake_config(attrs)
    return int(cfg.blockers) if "blockers" in cfg.model_fields_set else DEFAULT_SPHERES


def ship_shexp(run: RunDir, character: Any, order: int, n_spheres: int, opset: int = 17,
               base_meta: dict[str, Any] | None = None) -> dict[str, Any]:
    """Fit the run's sphere blockers (:func:`prt_torch.blockers.fit_spheres`) and write them
    (``RunDir.blockers_path``) and the whole-sphere SHEXP graph (``RunDir.shexp_path``, HYB,
    ``below_horizon`` none: the consumer applies the dataset's convention or composes products), each atomically;
    check ORT/torch parity. Returns the ``export.json`` entry."""
    from prt_torch.blockers import fit_spheres
    from prt_torch.export.onnx_file import initializer_bytes

    spheres = fit_spheres(character, n_spheres=min(int(n_spheres), int(character.num_vertices)))
    spheres.save(run.blockers_path)
    meta = {str(k): str(v) for k, v in (base_meta or {}).items()}
    meta.update({"prt.graph": "shexp", "prt.n_spheres": str(spheres.num_spheres)})
    path = export_shexp(run.shexp_path, order, "hyb", None, metadata=meta)
    par = shexp_parity(path, order)
    return {"n_spheres": spheres.num_spheres, "radius_quantile": spheres.radius_quantile, "method": "hyb",
            "below_horizon": "none", "order": order, "blockers_file": run.relative(run.blockers_path),
            "graph_file": run.relative(run.shexp_path), "inputs": list(SHEXP_INPUTS),
            "parity": {**par.as_dict(), "initializer_bytes": initializer_bytes(path), "file_bytes":
                       path.stat().st_size}}


def plan_stage(request: ExportRequest) -> Shipment:
    """The export plan: the blockers file and the SHEXP graph, every run; the key records the sphere count
    (:func:`blocker_count`) and :data:`SHEXP_GRAPH_VERSION`."""
    n_spheres = blocker_count(request.run)
    return Shipment(files=(request.run.blockers_path, request.run.shexp_path),
                    key={"blockers": n_spheres, "shexp_graph": SHEXP_GRAPH_VERSION}, state=n_spheres)


def ship_stage(shipment: Shipment, inputs: ShipInputs) -> dict[str, Any]:
    """:func:`ship_shexp` with the plan's sphere count: ``export.json``'s ``shexp`` entry."""
    return ship_shexp(inputs.run, inputs.character, inputs.order, shipment.state, inputs.opset, inputs.base_meta)


#: ``prt export``'s sphere blockers + SHEXP graph (:data:`prt_torch.export.shippers.SHIPPERS`)
SHIPPER = Shipper(name="shexp", plan=plan_stage, ship=ship_stage)

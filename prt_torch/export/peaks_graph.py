"""``peaks.onnx``: the learned peak visibility as an ONNX graph (issue 27; what onnxruntime-web runs in the page).

The graph is :class:`prt_torch.models.peak_blockers.PeakBlockers` with the run's fitted spheres or
capsules (``peak_blockers.npz``, either kind: :func:`prt_torch.blockers.capsules.load_blocker_set`) as
constants: inputs ``positions (B, V, 3)``, ``normals (B, V, 3)`` (posed, world),
``skin (B, J, 4, 4)`` (skinning matrices ``world @ inverse_bind``), ``directions (P, 3)`` (unit, towards the
lights) and ``angular_radii (P,)`` (radians); output ``peak_visibility (B, V, P)`` in ``[0, 1]``. ``B``, ``V`` and
``P`` are dynamic (the overlapping (receiver, sphere, peak) triples are gathered with ``NonZero``).

``prt export`` writes it for a run trained with ``train.peaks`` (:data:`SHIPPER`, the export's core shipper) and
checks it against the torch module on held-out frames (onnxruntime vs torch).

``fused_peaks.onnx`` (:class:`~prt_torch.export.graphs.FusedPeaksGraph`): the fused graph
(:class:`prt_torch.export.graphs.FusedGraph`, pose features -> visibility -> the residual's RPO radiance) with the
peak lights' term in the same graph: the learned blockers' visibility and
:func:`prt_torch.brdf.direct_graph.peak_radiance_graph` with the BRDF an input. Inputs: the fused graph's
(:data:`~prt_torch.export.graphs.FUSED_INPUTS`, vertex axes in its order) and :data:`FUSED_PEAK_INPUTS`: ``positions
(B, 3, V)`` (posed, world, the fused graph's vertex order), ``skin (B, J, 4, 4)``, ``peak_directions (P, 3)``,
``peak_radii (P,)``, ``peak_powers (P, 3)`` (``E`` times the BRDF's tint) and ``peak_brdf (1 + BRDF_PARAMS,)``
(:func:`prt_torch.brdf.direct.brdf_code`); outputs ``radiance (B, V, 3)`` (the whole: residual + peaks) and
``peak_visibility (B, V, P)``. A single graph for a runtime that plays one ONNX file (an engine, the browser); the
Python player's default keeps the compiled peak kernels after ``fused.onnx`` (faster on a CPU) and plays this one
with ``graph="fused_peaks"``.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from prt_torch.errors import check
from prt_torch.export.shippers import ExportRequest, ShipInputs, Shipment, Shipper
from prt_torch.rundir import file_sha256

PEAK_INPUTS = ("positions", "normals", "skin", "directions", "angular_radii")
PEAK_OUTPUTS = ("peak_visibility",)
#: the inputs :class:`~prt_torch.export.graphs.FusedPeaksGraph` adds to the fused graph's
FUSED_PEAK_INPUTS = ("positions", "skin", "peak_directions", "peak_radii", "peak_powers", "peak_brdf")
FUSED_PEAK_OUTPUTS = ("radiance", "peak_visibility")
#: bump when the graph's computation changes (the export stage key)
PEAKS_GRAPH_VERSION = 3  # 3: fused_peaks.onnx
#: ORT vs torch tolerance on the visible fractions (in [0, 1]): float32 trigonometry of the same formula, op
#: orders differing between the runtimes; on the example's 0.265-degree discs the float32 rounding of a fraction is
#: ~eps / r^2 at worst (eps ~ 6e-8, r in radians: 3e-3), measured on the demo's learned capsules 3e-4 (spheres 1e-4)
PARITY_RTOL = 1e-3


def example_peaks(n: int = 2, radius_deg: float = 0.265, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """``(directions (n, 3), angular_radii (n,))`` float32: ``n`` seeded sky directions, ``radius_deg`` discs."""
    from prt_torch.bake.peaks import record_directions

    return record_directions(0, n, 10.0, seed), np.full(n, math.radians(radius_deg), np.float32)


def export_peak_graph(spheres: Any, path: Any, inputs: dict[str, np.ndarray], metadata: dict[str, Any] | None = None,
                      opset: int = 17, exporter: str = "torchscript") -> Any:
    """Write the graph of ``spheres`` (a :class:`~prt_torch.blockers.spheres.SphereSet` or a
    :class:`~prt_torch.blockers.capsules.CapsuleSet`) to ``path`` (atomic) traced on ``inputs``
    (:data:`PEAK_INPUTS`); returns the torch module."""
    import torch

    from prt_torch.export.onnx_file import export_onnx
    from prt_torch.models.peak_blockers import PeakBlockers

    module = PeakBlockers(spheres).eval()
    args = [torch.from_numpy(np.ascontiguousarray(inputs[k], dtype=np.float32)) for k in PEAK_INPUTS]
    dyn = {"positions": {0: "B", 1: "V"}, "normals": {0: "B", 1: "V"}, "skin": {0: "B"}, "directions": {0: "P"},
           "angular_radii": {0: "P"}, "peak_visibility": {0: "B", 1: "V", 2: "P"}}
    meta = {**(metadata or {}), "prt.graph": "peaks", "prt.n_spheres": str(len(spheres.radius)),
            "prt.blockers": module.kind}
    export_onnx(module, args, path, PEAK_INPUTS, PEAK_OUTPUTS, dyn, metadata=meta, opset=opset, exporter=exporter)
    return module


def fused_peak_example(inputs: ShipInputs, skin: np.ndarray) -> dict[str, np.ndarray]:
    """The fused-peaks graph's parity inputs: the fused graph's, the held-out positions in its vertex order, their
    skinning matrices, :func:`example_peaks` with a sun-like power and a glossy Phong (every input used)."""
    from prt_torch.brdf.analytic import Phong
    from prt_torch.brdf.direct import brdf_code

    order = inputs.fused_graph.vertex_order
    pos = np.ascontiguousarray(inputs.held["positions"].transpose(0, 2, 1), dtype=np.float32)
    if order is not None:
        pos = np.ascontiguousarray(pos[:, :, order])
    dirs, radii = example_peaks()
    code, prm = brdf_code(Phong(exponent=16.0, kd=0.3, ks=0.7))  # type: ignore[misc]
    return {**inputs.fused_inputs, "positions": pos, "skin": skin.astype(np.float32), "peak_directions": dirs,
            "peak_radii": radii, "peak_powers": np.array([[3.0, 2.8, 2.5], [0.5, 0.5, 0.6]], np.float32)[:len(dirs)],
            "peak_brdf": np.r_[code, prm].astype(np.float32)}


def export_fused_peaks(inputs: ShipInputs, blockers: Any, skin: np.ndarray) -> dict[str, Any]:
    """Write ``fused_peaks.onnx`` (:class:`~prt_torch.export.graphs.FusedPeaksGraph`) and check it, onnxruntime vs
    torch, on the held-out frames; its ``export.json`` record."""
    import torch

    from prt_torch.export.graphs import FUSED_INPUTS, FusedPeaksGraph
    from prt_torch.export.onnx_file import export_onnx, initializer_bytes
    from prt_torch.export.parity import check_parity
    from prt_torch.models.peak_blockers import PeakBlockers

    run = inputs.run
    module = FusedPeaksGraph(inputs.fused_graph, PeakBlockers(blockers)).eval()
    ex = fused_peak_example(inputs, skin)
    names = (*FUSED_INPUTS, *FUSED_PEAK_INPUTS)
    batch = {0: "B"}
    dyn = {"pose": batch, "frames": batch, "view_dirs": batch, "positions": batch, "skin": batch,
           "peak_directions": {0: "P"}, "peak_radii": {0: "P"}, "peak_powers": {0: "P"},
           "radiance": batch, "peak_visibility": {0: "B", 2: "P"}}
    path = run.fused_peaks_graph_path
    meta = {**inputs.base_meta, "prt.graph": "fused_peaks", "prt.blockers": module.blockers.kind,
            "prt.vertex_order": "cluster" if inputs.fused_graph.vertex_order is not None else "original"}
    args = [torch.from_numpy(np.ascontiguousarray(ex[k])) for k in names]
    export_onnx(module, args, path, names, FUSED_PEAK_OUTPUTS, dyn, metadata=meta, opset=inputs.opset,
                exporter=inputs.exporter, **inputs.lowered)
    with torch.no_grad():
        par = check_parity(module, path, {k: ex[k] for k in names}, rtol=max(inputs.rtol, PARITY_RTOL))
    inputs.log(f"  {path.name}: parity rel. error {par.rel_error:.2e} on {len(ex['pose'])} held-out poses")
    return {"graph_file": run.relative(path), "inputs": list(names), "outputs": list(FUSED_PEAK_OUTPUTS),
            "parity": {**par.as_dict(), "initializer_bytes": initializer_bytes(path),
                       "file_bytes": path.stat().st_size}}


def plan_peaks(request: ExportRequest) -> Shipment:
    """A run with learned peak blockers ships ``peaks.onnx``; the key records the blockers' sha256."""
    p = request.run.peak_blockers_path
    if not p.is_file():
        return Shipment()
    return Shipment(files=(request.run.peak_graph_path, request.run.fused_peaks_graph_path),
                    key={"peak_blockers_sha256": file_sha256(p), "peaks_graph": PEAKS_GRAPH_VERSION})


def ship_peaks(shipment: Shipment, inputs: ShipInputs) -> dict[str, Any] | None:
    """Export ``peaks.onnx`` and check it (ORT vs torch) on the held-out frames: ``export.json``'s ``peaks``."""
    if not shipment.files:
        return None
    import torch

    from prt_torch.blockers.capsules import load_blocker_set
    from prt_torch.export.onnx_file import initializer_bytes
    from prt_torch.export.parity import check_parity

    run = inputs.run
    spheres = load_blocker_set(run.peak_blockers_path)
    held = inputs.held
    from prt_torch.bake.deformable import is_deformable

    check(not is_deformable(run.dataset().attrs), f"{run.path}: learned peak blockers need a skinned character")
    _, skin, _ = run.dataset().row_poses(held["rows"], inputs.character)
    dirs, radii = example_peaks()
    ex = {"positions": held["positions"].astype(np.float32),
          "normals": np.ascontiguousarray(held["frames"][..., 2, :], dtype=np.float32),
          "skin": skin.astype(np.float32), "directions": dirs, "angular_radii": radii}
    path = run.peak_graph_path
    module = export_peak_graph(spheres, path, ex, inputs.base_meta, inputs.opset, inputs.exporter)
    with torch.no_grad():
        par = check_parity(module, path, ex, rtol=PARITY_RTOL)
    inputs.log(f"  {path.name}: parity rel. error {par.rel_error:.2e} on {len(ex['positions'])} held-out poses")
    return {"graph_file": run.relative(path), "blockers_file": run.relative(run.peak_blockers_path),
            "n_spheres": int(len(spheres.radius)), "blockers": module.kind, "inputs": list(PEAK_INPUTS),
            "outputs": list(PEAK_OUTPUTS),
            "parity": {**par.as_dict(), "initializer_bytes": initializer_bytes(path), "file_bytes":
                       path.stat().st_size},
            "fused": export_fused_peaks(inputs, spheres, skin)}


#: the export's core shipper of the learned peak graph (``prt_torch.export.run`` ships it before the methods')
SHIPPER = Shipper(name="peaks", plan=plan_peaks, ship=ship_peaks)

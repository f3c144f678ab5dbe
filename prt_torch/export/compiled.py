"""The compiled frame path's data (``prt export``): the model split where its per-cluster output bases begin.

The player's default CPU path (:mod:`prt_torch.player.compiled`) runs the small part of the visibility model in
onnxruntime and decodes + shades every vertex cluster in one compiled pass, with the fused graph's own numbers:

* ``latent.onnx`` (:class:`LatentGraph`): ``pose (B, A) -> z (B, G, K)``, the model's input projection and regressor
  (the fused graph's first half, lowered to the same precision);
* ``decode.npz`` (:func:`decode_arrays`, format :data:`DECODE_FORMAT`): the fused graph's per-cluster output bases in
  its cluster-sorted vertex order, exactly as its ``MatMulNBits`` (int8) or ``MatMul`` (fp32 / fp16) nodes hold them.
  Cluster ``g`` (clusters with vertices, in vertex order) owns vertices ``starts[g] .. starts[g] + n_used[g]`` of the
  cluster-sorted order and the columns ``(coefficient c, vertex i) -> c * n_used[g] + i`` of its basis
  ``(k_used[g], C * n_used[g])``:

  - int8: ``q`` int8 flat, cluster ``g``'s ``(C * n_g, n_blocks_g, block_g)`` block at ``q_offsets[g]`` (the
    :func:`~prt_torch.export.graphs.int8_quantize` layout of the ONNX lowering, rows past ``k_used`` zero);
    ``scales`` float32 flat ``(C * n_g, n_blocks_g)`` at ``scale_offsets[g]``; ``blocks (G,)``;
  - fp32 / fp16: ``weights`` float32 flat, cluster ``g``'s ``(k_used[g], C * n_g)`` at ``q_offsets[g]`` (fp16 bases
    widened: the values the CPU provider multiplies with);
  - ``mean (C, V)`` float32 in cluster-sorted order (float16-rounded for int8, as the int8 export stores it),
    ``clusters (G,)`` the cluster index of each entry in ``z``'s axis 1.

Shipped for a skinned run whose model has per-cluster output bases (:func:`prt_torch.export.run.per_cluster`); the
player plays the fused graph otherwise.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from prt_torch.errors import check
from prt_torch.export.shippers import ExportRequest, ShipInputs, Shipment, Shipper
from prt_torch.io import atomic_path

#: ``decode.npz``'s layout version (part of the export key: a new layout re-exports)
DECODE_FORMAT = 1
#: the latent graph's input and output names
LATENT_INPUTS, LATENT_OUTPUTS = ("pose",), ("latent",)


def _latent_module(vis_graph: Any) -> Any:
    """``pose -> z``: the :class:`~prt_torch.export.graphs.VisibilityGraph` ``vis_graph`` without its output bases
    (a torch module; torch is imported here, at export time only)."""
    from torch import nn

    class LatentGraph(nn.Module):
        """``pose (B, A) -> z (B, G, K)``: the input projection and regressor of a per-cluster visibility graph."""

        def __init__(self, graph: Any) -> None:
            super().__init__()
            self.graph = graph

        def forward(self, pose: Any) -> Any:
            return self.graph.model.regressor(self.graph.inp(pose))

    return LatentGraph(vis_graph)


def decode_arrays(unprojection: Any) -> dict[str, np.ndarray]:
    """``decode.npz``'s arrays (module doc) of a cluster-sorted
    :class:`~prt_torch.export.graphs.CompactUnprojection`."""
    from prt_torch.export.graphs import int8_quantize

    u = unprojection
    check(u.cluster_sorted, "the compiled frame path needs a cluster-sorted output unprojection")
    c = u.n_coeffs
    int8 = u.precision == "int8"
    clusters, n_used, k_used, blocks, q_off, s_off, parts, scales = [], [], [], [], [], [], [], []
    q_at = s_at = 0
    for g in range(u.n_groups):
        if not u.n_used[g]:
            continue
        w = getattr(u, f"basis_{g}").detach().float().numpy()  # (K_g, C * n_g), columns (coefficient, vertex)
        clusters.append(g)
        n_used.append(u.n_used[g])
        k_used.append(w.shape[0])
        q_off.append(q_at)
        s_off.append(s_at)
        if int8 and w.size:
            q, s, block = int8_quantize(w)  # the same call as the ONNX lowering: the same bytes
            parts.append(q.reshape(-1))
            scales.append(s.reshape(-1))
            blocks.append(block)
            q_at += q.size
            s_at += s.size
        else:
            parts.append(w.reshape(-1))
            blocks.append(0)
            q_at += w.size
    starts = np.concatenate([[0], np.cumsum(n_used)[:-1]]).astype(np.int64)
    out = {"format": np.int64(DECODE_FORMAT), "precision": np.array(u.precision), "n_coeffs": np.int64(c),
           "clusters": np.asarray(clusters, np.int64), "n_used": np.asarray(n_used, np.int64),
           "k_used": np.asarray(k_used, np.int64), "starts": starts, "blocks": np.asarray(blocks, np.int64),
           "q_offsets": np.asarray(q_off, np.int64), "scale_offsets": np.asarray(s_off, np.int64),
           "mean": np.ascontiguousarray(u.mean.detach().float().numpy().reshape(c, -1))}
    if int8:
        out["q"] = np.concatenate(parts).astype(np.int8) if parts else np.zeros(0, np.int8)
        out["scales"] = np.concatenate(scales).astype(np.float32) if scales else np.zeros(0, np.float32)
    else:
        out["weights"] = np.concatenate(parts).astype(np.float32) if parts else np.zeros(0, np.float32)
    return out


def plan_compiled(request: ExportRequest) -> Shipment:
    """A skinned run with per-cluster output bases ships ``latent.onnx`` and ``decode.npz``."""
    if not request.per_cluster or request.deformable:
        return Shipment()
    run = request.run
    return Shipment(files=(run.latent_graph_path, run.decode_path), key={"decode_format": DECODE_FORMAT})


def ship_compiled(shipment: Shipment, inputs: ShipInputs) -> dict[str, Any] | None:
    """Export ``latent.onnx`` (parity against torch on the held-out poses) and write ``decode.npz`` from the fused
    graph's output bases: ``export.json``'s ``compiled`` entry."""
    run = inputs.run
    if not shipment.files:
        for p in (run.latent_graph_path, run.decode_path):
            p.unlink(missing_ok=True)
        return None
    import torch

    from prt_torch.export.graphs import set_int8_emulation
    from prt_torch.export.onnx_file import export_onnx, initializer_bytes
    from prt_torch.export.parity import check_parity

    fused = inputs.fused_graph
    module = _latent_module(fused.model).eval()
    pose = np.ascontiguousarray(inputs.held["pose"], dtype=np.float32)
    path = run.latent_graph_path
    meta = {**inputs.base_meta, "prt.graph": "latent"}
    export_onnx(module, [torch.from_numpy(pose)], path, LATENT_INPUTS, LATENT_OUTPUTS,
                {"pose": {0: "B"}, "latent": {0: "B"}}, metadata=meta, opset=inputs.opset, exporter=inputs.exporter,
                **inputs.lowered)
    set_int8_emulation(module, True)
    try:
        par = check_parity(module, path, {"pose": pose}, rtol=inputs.rtol)
    finally:
        set_int8_emulation(module, False)
    inputs.log(f"  {path.name}: parity rel. error {par.rel_error:.2e} on {len(pose)} held-out poses")
    arrays = decode_arrays(fused.model.out)
    with atomic_path(run.decode_path) as tmp:
        with open(tmp, "wb") as f:
            np.savez(f, **arrays)
    return {"latent_file": run.relative(path), "decode_file": run.relative(run.decode_path),
            "decode_format": DECODE_FORMAT,
            "parity": {**par.as_dict(), "initializer_bytes": initializer_bytes(path),
                       "file_bytes": path.stat().st_size}}


#: the export's core shipper of the compiled frame path's data (``prt_torch.export.run`` ships it first)
SHIPPER = Shipper(name="compiled", plan=plan_compiled, ship=ship_compiled)

"""``export_run(run_dir)``: a trained run -> ONNX graphs + RPO files + export metadata.

Writes into the run directory (file names: :class:`prt_torch.rundir.RunDir`):

* the visibility graph: ``pose (B, A) -> visibility (B, V, C)`` (local frame);
* the shading graph: ``visibility (B, V, C), frames (B, 9, V), view_dirs (B, 3, V), lobe_dirs (K, 3),
  lobe_coeffs (K, n, 3), rpo_M (k, C, C), rpo_w (k, C), rpo_tint (3,) -> radiance (B, V, 3)``
  (:class:`prt_torch.export.graphs.ShadingGraph`; frames and view directions vertex-last);
* the fused graph: the two in one (``pose`` instead of ``visibility``), with every vertex axis (frames and
  view_dirs in, radiance out) in CLUSTER-SORTED order - the vertex-order contract of format /3: the frame
  data's ``vertex_order (V,)`` lists the original vertex at each position (``export.json`` ``fused_vertex_order:
  "cluster"``; absent / ``"original"``: identity), so the model's output unprojection is one contiguous block
  GEMM per cluster with no gather; the player poses in that order and returns radiance in the original order.
  The visibility and shading graphs keep the original order (the compare yardstick, the web viewer);
* the output bases in ``precision`` (:data:`prt_torch.export.graphs.PRECISIONS`) in the visibility and fused
  graphs;
* one RPO file per named BRDF (loadable without torch), the cluster data of the vertex frames;
* what the method packages ship (:data:`prt_torch.export.shippers.SHIPPERS`: the sphere blockers and the SHEXP
  graph, the learned transfer graph, a deformable run's deform data and positions-in graphs, its local network),
  each shipper giving its files, its part of the stage key and its ``export.json`` entry;
* the export metadata: sizes, conventions, file names, parity errors, character hash - everything the
  player needs besides the character file.

Up to date when the run's ``export`` stage key (model file hash + export settings + the shippers' parts) is
unchanged and every file exists (:meth:`prt_torch.rundir.RunDir.is_current`) and verifies against the metadata.

One committed unit: the stage first drops its ``stages.json`` key and stale temporaries
(:meth:`RunDir.begin`), writes the frame data, the RPO files and the graphs (each atomically), then the
export metadata LAST with the sha256 of each of them (``file_sha256``) and of the model it was exported
from (``model_file``, ``model_sha256``): it is the commit record. A kill before it is renamed leaves files
that disagree with the old metadata, which every reader (:meth:`RunDir.export_meta`, the player's
:class:`prt_torch.player.bundle.RunBundle`) refuses with one line saying to re-run ``prt export``.

Each graph is checked by ``onnx.checker`` and against torch on held-out poses (relative error <= 1e-4
in float32, else :class:`PrtError`). Every file is written atomically.
"""

from __future__ import annotations

import os
import time
from pathlib import Path
from typing import Any

import numpy as np

from prt_torch.bake.deformable import is_deformable
from prt_torch.brdf.rpo import DEFAULT_TERMS
from prt_torch.errors import ArtifactError, MissingArtifact, check
from prt_torch.export.shippers import ExportRequest, ShipInputs, merge_parts, shippers
from prt_torch.io import atomic_write_json
from prt_torch.metrics import evenly_spaced_indices
from prt_torch.rundir import GRAPHS, RunDir, file_sha256, stage_key

FORMAT = "prt_torch.export/3"  # /2: file_sha256, model_file (the commit record); /3: precision, cluster-sorted fused

#: the default weight precision of the exported bases (:data:`prt_torch.export.graphs.PRECISIONS`): int8 halves
#: the visibility model's per-frame time on the CPU provider at an image cost well under 0.5 dB (prt compare rows
#: learned_mlp_int8 / _fp16 / _fp32 and prt bench play measure it)
DEFAULT_PRECISION = "int8"

#: the ONNX weight initializers the precision applies to: the per-cluster output bases
BASIS_PATTERN = r"basis_\d+$"
#: the ONNX initializers an int8 export stores in float16: the output mean (CompactUnprojection rounds it alike)
MEAN_PATTERN = r"out\.mean$"
#: what an int8 export's graphs hold (part of the export key of int8 exports only): 2 = the input projection int8
#: too and the output mean in float16 (1: the output bases alone), so an older int8 export is re-exported
INT8_LAYOUT = 2


def lowering(precision: str) -> dict[str, str | None]:
    """The :func:`~prt_torch.export.onnx_file.export_onnx` keyword arguments of a weight precision: int8 lowers the
    bases to MatMulNBits (``int8_weights``) and stores the output mean in float16 (``fp16_weights``)."""
    int8 = precision == "int8"
    return {"int8_weights": BASIS_PATTERN if int8 else None, "fp16_weights": MEAN_PATTERN if int8 else None}

#: ONNX vs torch parity tolerance (relative to the output's max) per precision: the int8 reference rounds its
#: GEMM inputs as onnxruntime does, but a float32 rounding difference upstream can move an activation across a
#: quantisation tie (one step = 1/255 of its range): 5.8e-4 measured on the 7.7k flag (185 components per
#: cluster); float16 GEMMs accumulate differently in torch and onnxruntime
PARITY_RTOL_BY_PRECISION = {"fp32": 1e-4, "fp16": 3e-3, "int8": 1e-3}

#: default BRDFs exported with every run (:func:`prt_torch.brdf.rpo.builtin_rpo` names)
DEFAULT_BRDFS = ("lambert", "phong", "ggx", "ward")

CONVENTIONS = ("z-up world; real SH orthonormal, index l*(l+1)+m, no Condon-Shortley phase (Ramamoorthi-Hanrahan); "
               "visibility in the local vertex frame rows (t, b, n), zero below the horizon; ZH lobe f_lm = g_l "
               "y_lm(s); RPO shading L = tint * sum_b (w_b . y(wo)) (l . M_b v) (seed 003 eq. 11)")


def export_conventions(below_horizon: str) -> str:
    """The conventions text of an export whose dataset was baked with ``bake.below_horizon = below_horizon``."""
    if below_horizon == "zero":
        return CONVENTIONS
    return CONVENTIONS.replace("zero below the horizon", "one below the horizon (seed 003 eq. 1)")


def heldout_inputs(run: RunDir, n_max: int = 8) -> dict[str, np.ndarray]:
    """Held-out poses, frames and positions of the run's dataset (``n_max`` evenly spaced done held-out
    frames; the last done frames when it has no held-out split)."""
    ds = run.dataset()
    rows = ds.split_rows("heldout") if "heldout" in ds.splits else np.zeros(0, np.int64)
    if rows.size == 0:
        rows = np.flatnonzero(ds.done)[-n_max:]
    check(rows.size > 0, f"{ds.path}: no finished frames to check parity on")
    rows = np.unique(rows[evenly_spaced_indices(rows.size, min(n_max, rows.size))])
    data = ds.rows(rows, ("pose", "frames", "positions"))
    return {k: np.asarray(v, dtype=np.float32) for k, v in data.items()} | {"rows": rows}


def dataset_is_deformable(run: RunDir) -> bool:
    """Whether the run's dataset is a deformable one (:func:`prt_torch.bake.deformable.is_deformable` of its attrs;
    False without a dataset)."""
    try:
        attrs = dict(run.dataset().attrs)
    except MissingArtifact:
        return False
    return is_deformable(attrs)


def write_frame_data(run: RunDir, vertex_order: np.ndarray | None = None) -> Path:
    """Copy the dataset's ``cluster (V,)``, ``cluster_axis (Kc, 3)``, ``cluster_bone (Kc,)`` to the run's
    frame-data file (atomically): the player rebuilds the vertex frames from them. ``vertex_order (V,)``: the
    fused graph's vertex order (original vertex at each position), stored when given."""
    from prt_torch.io import atomic_path

    ds = run.dataset()
    missing = [k for k in ("cluster", "cluster_axis", "cluster_bone") if k not in ds]
    check(not missing, f"{ds.path}: missing frame data {missing} (re-bake the dataset)")
    out = run.frames_path
    with atomic_path(out) as tmp:
        with open(tmp, "wb") as f:
            extra = {} if vertex_order is None else {"vertex_order": np.asarray(vertex_order, dtype=np.int32)}
            np.savez(f, cluster=ds.cluster.astype(np.int32), cluster_axis=ds.cluster_axis.astype(np.float32),
                     cluster_bone=ds.cluster_bone.astype(np.int32), **extra)
    return out


def _view_dirs(positions: np.ndarray, eye: np.ndarray) -> np.ndarray:
    """``(B, 3, V)`` vertex-last unit directions from ``positions (B, V, 3)`` to ``eye (3,)``."""
    d = eye[None, None, :] - positions
    d = d / np.linalg.norm(d, axis=-1, keepdims=True)
    return np.ascontiguousarray(d.transpose(0, 2, 1), dtype=np.float32)


def _frames_vertex_last(frames: np.ndarray) -> np.ndarray:
    """``(B, V, 3, 3) -> (B, 9, V)``."""
    b, v = frames.shape[:2]
    return np.ascontiguousarray(frames.reshape(b, v, 9).transpose(0, 2, 1), dtype=np.float32)


def default_eye(positions: np.ndarray) -> np.ndarray:
    """A camera position in front of (-y), slightly above, the mesh ``(..., V, 3)``."""
    p = positions.reshape(-1, 3)
    lo, hi = p.min(0), p.max(0)
    c = 0.5 * (lo + hi)
    size = float(np.linalg.norm(hi - lo))
    return (c + np.array([0.35, -1.0, 0.25]) * 1.6 * size).astype(np.float32)


def export_run(run_dir: str | os.PathLike[str] | RunDir, kind: str | None = None,
               brdfs: tuple[str, ...] = DEFAULT_BRDFS, n_terms: int = DEFAULT_TERMS, opset: int = 17,
               exporter: str = "torchscript", force: bool = False,
               console: Any = None, precision: str = DEFAULT_PRECISION, deform: Any = None) -> dict[str, Any]:
    """Export a trained run to ONNX while holding the run directory's lock (:meth:`RunDir.lock`); see
    :func:`_export_run` for the arguments. Returns the export metadata."""
    run = RunDir.of(run_dir).require()
    with run.lock("export"):
        return _export_run(run, kind=kind, brdfs=brdfs, n_terms=n_terms, opset=opset, exporter=exporter,
                           force=force, console=console, precision=precision, deform=deform)


def _export_run(run_dir: str | os.PathLike[str] | RunDir, kind: str | None = None,
                brdfs: tuple[str, ...] = DEFAULT_BRDFS, n_terms: int = DEFAULT_TERMS, opset: int = 17,
                exporter: str = "torchscript", force: bool = False,
                console: Any = None, precision: str = DEFAULT_PRECISION, deform: Any = None) -> dict[str, Any]:
    """Export a trained run to ONNX; returns the ``export.json`` content.

    Args:
        run_dir: ``runs/NAME`` holding the trained model, the character and the dataset (for the
            held-out parity check).
        kind: model kind (``None``: the run's default model).
        brdfs: named BRDFs to turn into RPO files (order of the model, ``n_terms`` terms).
        n_terms: BRDF terms ``k`` of the shading graph (RPOs with fewer terms are zero-padded at run time).
        opset: ONNX opset (>= 17).
        exporter: ``"torchscript"`` or ``"dynamo"``.
        force: re-export even when the export is up to date (same model file and settings).
        precision: weight precision of the output bases (``"fp32"``, ``"fp16"``, ``"int8"``); models without
            per-cluster bases export in float32.
        deform: a deformable run's spec, handed to the shippers (:class:`~prt_torch.export.shippers.ExportRequest`;
            cloth: a :class:`prt_torch.cloth.export.DeformSpec`; ``None``: built from the run when its dataset is
            deformable): the deformable shipper ships the deform data and the positions-in graph too.
    """
    import torch

    from prt_torch.export.graphs import (
        FUSED_INPUTS,
        PRECISIONS,
        SHADING_INPUTS,
        FusedGraph,
        ShadingGraph,
        VisibilityGraph,
        set_int8_emulation,
    )
    from prt_torch.export.onnx_file import export_onnx, initializer_bytes
    from prt_torch.export.parity import check_parity
    from prt_torch.models.visibility import load_model, model_path

    check(precision in PRECISIONS, f"unknown precision {precision!r}: expected one of {list(PRECISIONS)}")
    run = RunDir.of(run_dir).require()
    mpath = model_path(run, kind)
    model = load_model(run, kind)
    model_hash = file_sha256(mpath)
    request = ExportRequest(run=run, precision=precision, opset=opset, exporter=exporter, deform=deform,
                            deformable=deform is not None or dataset_is_deformable(run), per_cluster=per_cluster(model))
    from prt_torch.export.compiled import SHIPPER as COMPILED_SHIPPER
    from prt_torch.export.peaks_graph import SHIPPER as PEAKS_SHIPPER

    # the core's compiled-path data and learned peak graph, then the method parts (SHIPPERS), all planned before
    # anything is written
    plans = [(s, s.plan(request)) for s in (COMPILED_SHIPPER, PEAKS_SHIPPER, *shippers())]
    ship_files = tuple(f for _, plan in plans for f in plan.files)
    core_key = {"model_sha256": model_hash, "n_terms": n_terms, "opset": opset, "exporter": exporter,
                "brdfs": sorted(brdfs), "precision": precision, "format": FORMAT,
                **({"int8_layout": INT8_LAYOUT} if precision == "int8" else {})}
    key = stage_key(merge_parts(core_key, [plan.key for _, plan in plans], "export stage key"))
    outputs = (run.export_json, run.frames_path, *(run.graph_path(g) for g in GRAPHS),
               *(run.rpo_path(b) for b in brdfs), *ship_files)
    if not force and run.is_current("export", key, outputs):
        try:
            return run.export_meta()
        except ArtifactError:
            pass  # damaged since: export again
    run.begin("export", outputs)
    character = run.character()
    check(character.num_vertices == model.n_vertices,
          f"model has {model.n_vertices} vertices but {run.character_path} has {character.num_vertices}")
    check(request.deformable or character.feature_width == model.n_features,  # deformable: its shipper checks
          f"model takes {model.n_features} pose features but the character gives {character.feature_width}")
    order, V, A, C = model.order, model.n_vertices, model.n_features, model.n_coeffs
    held = heldout_inputs(run)
    vis_graph = VisibilityGraph(model, precision=precision if per_cluster(model) else "fp32").eval()
    precision = vis_graph.precision
    fused_graph = FusedGraph(model, order, n_terms, cluster_sorted=True, precision=precision).eval()
    vorder = fused_graph.vertex_order  # None: the model has no per-vertex clusters, the fused graph stays original
    write_frame_data(run, vorder)
    check(held["frames"].shape[1] == V, f"dataset has {held['frames'].shape[1]} vertices, the model {V}")
    from prt_torch.bake.store import below_horizon_of

    below_horizon = below_horizon_of(run.dataset().attrs)  # the player's unshadowed visibility follows it
    conventions = export_conventions(below_horizon)
    rpos = build_rpos(brdfs, order, n_terms)
    rpo_files = {}
    for name, rpo in rpos.items():
        rpo.save(run.rpo_path(name))
        rpo_files[name] = run.relative(run.rpo_path(name))

    base_meta = {
        "prt.format": FORMAT, "prt.conventions": conventions, "prt.sh_order": order, "prt.n_coeffs": C,
        "prt.n_vertices": V, "prt.n_features": A, "prt.n_terms": n_terms, "prt.model_kind": model.kind,
        "prt.character_hash": character.content_hash(), "prt.character_name": character.name,
        "prt.model_sha256": model_hash,
        "prt.frames": "frames input (B, 9, V): entry 3i+j = F[i, j], rows (t, b, n), world; local = F @ w",
        "prt.view_dirs": "(B, 3, V) unit world directions vertex -> eye",
        "prt.below_horizon": below_horizon,
        "prt.precision": precision,
    }
    batch = {0: "B"}
    shade_graph = ShadingGraph(order, n_terms).eval()

    # example / parity inputs: held-out poses with their baked frames, a camera, 3 lobes, an RPO
    pose = held["pose"]
    eye = default_eye(held["positions"])
    lobes = _example_lobes(order)
    rpo = next(iter(rpos.values()))
    M, w = pad_rpo(rpo, n_terms)
    with torch.no_grad():
        vis = vis_graph(torch.from_numpy(pose)).numpy()
    shade_in = {"visibility": vis, "frames": _frames_vertex_last(held["frames"]),
                "view_dirs": _view_dirs(held["positions"], eye),
                "lobe_dirs": lobes[0], "lobe_coeffs": lobes[1], "rpo_M": M, "rpo_w": w,
                "rpo_tint": np.asarray(rpo.tint, dtype=np.float32)}
    fused_in = {"pose": pose, **{k: shade_in[k] for k in SHADING_INPUTS[1:]}}
    if vorder is not None:  # the fused graph's vertex axes in export (cluster-sorted) order
        fused_in["frames"] = np.ascontiguousarray(fused_in["frames"][:, :, vorder])
        fused_in["view_dirs"] = np.ascontiguousarray(fused_in["view_dirs"][:, :, vorder])
    dyn_shade = {"visibility": batch, "frames": batch, "view_dirs": batch, "radiance": batch}
    dyn_fused = {"pose": batch, "frames": batch, "view_dirs": batch, "radiance": batch}
    t0 = time.perf_counter()
    parity: dict[str, Any] = {}
    specs = [("visibility", vis_graph, {"pose": pose}, ("pose",), ("visibility",),
              {"pose": batch, "visibility": batch}),
             ("shading", shade_graph, shade_in, SHADING_INPUTS, ("radiance",), dyn_shade),
             ("fused", fused_graph, fused_in, FUSED_INPUTS, ("radiance",), dyn_fused)]
    for graph_name, module, inputs, in_names, out_names, dyn in specs:
        path = run.graph_path(graph_name)
        args = [torch.from_numpy(np.ascontiguousarray(inputs[k], dtype=np.float32)) for k in in_names]
        g_meta = {**base_meta, "prt.graph": graph_name,
                  "prt.vertex_order": "cluster" if graph_name == "fused" and vorder is not None else "original"}
        if graph_name == "shading":
            g_meta["prt.precision"] = "fp32"
        export_onnx(module, args, path, in_names, out_names, dyn, metadata=g_meta, opset=opset, exporter=exporter,
                    **lowering(precision if graph_name != "shading" else "fp32"))
        set_int8_emulation(module, True)
        try:
            p = check_parity(module, path, {k: inputs[k] for k in in_names},
                             rtol=PARITY_RTOL_BY_PRECISION[precision])
        finally:
            set_int8_emulation(module, False)
        parity[graph_name] = {**p.as_dict(), "initializer_bytes": initializer_bytes(path),
                              "file_bytes": path.stat().st_size}
        if console is not None:
            console.print(f"  {path.name}: parity rel. error {p.rel_error:.2e} on {len(pose)} held-out poses")
    inputs = ShipInputs(run=run, character=character, order=order, opset=opset, exporter=exporter,
                        precision=precision, rtol=PARITY_RTOL_BY_PRECISION[precision], lowered=lowering(precision),
                        base_meta=base_meta, held=held, vis_graph=vis_graph, fused_graph=fused_graph,
                        fused_inputs=fused_in, console=console)
    shipped = {}
    for shipper, plan in plans:
        part = shipper.ship(plan, inputs)
        if part is not None:
            shipped[shipper.name] = part
    meta = {
        "format": FORMAT, "conventions": conventions, "below_horizon": below_horizon, "sh_order": order,
        "n_coeffs": C, "n_vertices": V, "n_features": A, "n_terms": n_terms, "model_kind": model.kind,
        "model_sha256": model_hash, "opset": opset, "precision": precision,
        "fused_vertex_order": "cluster" if vorder is not None else "original",
        "exporter": exporter, "character_hash": character.content_hash(), "character_name": character.name,
        "character_file": run.relative(run.character_path), "frames_file": run.relative(run.frames_path),
        "files": {g: run.relative(run.graph_path(g)) for g in GRAPHS},
        "inputs": {"visibility": ["pose"], "shading": list(SHADING_INPUTS), "fused": list(FUSED_INPUTS)},
        "brdfs": sorted(rpo_files), "rpo_files": rpo_files, "parity": parity,
        "parity_rows": held["rows"].tolist(), "export_seconds": time.perf_counter() - t0,
        "model_file": run.relative(mpath),
        "file_sha256": run.unit_hashes([run.frames_path, *(run.rpo_path(b) for b in rpo_files),
                                        *(run.graph_path(g) for g in GRAPHS), *ship_files]),
    }
    meta = merge_parts(meta, [shipped], run.relative(run.export_json))
    atomic_write_json(run.export_json, meta)  # the commit record: written last
    run.mark_done("export", key)
    return meta


def per_cluster(model: Any) -> bool:
    """Whether ``model`` has the per-cluster output bases that the precision and the cluster order apply to."""
    from prt_torch.models.projection import OutputUnprojection

    return isinstance(getattr(model, "out", None), OutputUnprojection)


def _example_lobes(order: int) -> tuple[np.ndarray, np.ndarray]:
    """Three fixed ZH lobes ``(dirs (3, 3), coeffs (3, n, 3))`` with decaying bands, for tracing/parity."""
    dirs = np.array([[0.3, -0.4, 0.866], [-0.7, 0.2, 0.3], [0.1, 0.9, -0.4]], dtype=np.float64)
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    bands = 0.6 ** np.arange(order)
    coeffs = bands[None, :, None] * np.array([[1.0, 0.9, 0.8], [0.3, 0.35, 0.5], [0.2, 0.15, 0.1]])[:, None, :]
    return dirs.astype(np.float32), coeffs.astype(np.float32)


def pad_rpo(rpo: Any, n_terms: int) -> tuple[np.ndarray, np.ndarray]:
    """``(M (k, C, C), w (k, C))`` float32 of an RPO zero-padded to ``n_terms`` terms."""
    M = np.asarray(rpo.M, dtype=np.float32)
    w = np.asarray(rpo.w, dtype=np.float32)
    k = M.shape[0]
    check(k <= n_terms, f"RPO {getattr(rpo, 'name', '?')!r} has {k} terms, the shading graph at most {n_terms}")
    if k < n_terms:
        M = np.concatenate([M, np.zeros((n_terms - k,) + M.shape[1:], np.float32)])
        w = np.concatenate([w, np.zeros((n_terms - k, w.shape[1]), np.float32)])
    return np.ascontiguousarray(M), np.ascontiguousarray(w)


def build_rpos(names: tuple[str, ...] | list[str], order: int, n_terms: int) -> dict[str, Any]:
    """Named RPOs of ``order`` with ``n_terms`` terms (via :mod:`prt_torch.brdf`)."""
    from prt_torch.brdf.rpo import builtin_rpo

    check(len(names) > 0, "export needs at least one BRDF")
    return {name: builtin_rpo(name, order=order, k=n_terms) for name in names}

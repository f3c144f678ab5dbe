"""``export_run(run_dir)``: a trained run -> ONNX graphs + RPO files + ``export.json``.

Writes into ``run_dir``:

* ``visibility.onnx``: ``pose (B, A) -> visibility (B, V, C)`` (local frame);
* ``shading.onnx``: ``visibility (B, V, C), frames (B, 9, V), view_dirs (B, 3, V), lobe_dirs (K, 3),
  lobe_coeffs (K, n, 3), rpo_M (k, C, C), rpo_w (k, C), rpo_tint (3,) -> radiance (B, V, 3)``
  (:class:`prt_torch.export.graphs.ShadingGraph`; frames and view directions vertex-last);
* ``fused.onnx``: the two in one graph (``pose`` instead of ``visibility``);
* ``rpo/<name>.npz`` for each named BRDF (loadable without torch);
* ``export.json``: sizes, conventions, file names, parity errors, character hash - everything the
  player needs besides ``character.npz``.

Each graph is checked by ``onnx.checker`` and against torch on held-out poses (relative error <= 1e-4
in float32, else :class:`PrtError`). Every file is written atomically.
"""

from __future__ import annotations

import hashlib
import json
import os
import time
from pathlib import Path
from typing import Any

import numpy as np

from prt_torch.errors import PrtError, check
from prt_torch.io import atomic_write_json

#: ONNX files and metadata file names inside a run directory
VISIBILITY_FILE = "visibility.onnx"
SHADING_FILE = "shading.onnx"
FUSED_FILE = "fused.onnx"
EXPORT_JSON = "export.json"
RPO_DIR = "rpo"
FORMAT = "prt_torch.export/1"

#: default BRDFs exported with every run (:func:`prt_torch.brdf.rpo.builtin_rpo` names)
DEFAULT_BRDFS = ("lambert", "phong", "ggx", "ward")

CONVENTIONS = ("z-up world; real SH orthonormal, index l*(l+1)+m, no Condon-Shortley phase (Ramamoorthi-Hanrahan); "
               "visibility in the local vertex frame rows (t, b, n), zero below the horizon; ZH lobe f_lm = g_l "
               "y_lm(s); RPO shading L = tint * sum_b (w_b . y(wo)) (l . M_b v) (seed 003 eq. 11)")


def _sha256_file(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def heldout_inputs(run_dir: Path, n_max: int = 8) -> dict[str, np.ndarray]:
    """Held-out poses, frames and positions from ``run_dir/dataset.zarr`` (first ``n_max`` held-out rows).

    Falls back to the last rows of the dataset when it has no held-out split.
    """
    import zarr

    path = run_dir / "dataset.zarr"
    if not path.exists():
        raise PrtError(f"no dataset in {run_dir} (dataset.zarr missing): cannot check parity on held-out poses")
    g = zarr.open_group(str(path), mode="r")
    clip_names = list(g.attrs.get("clip_names", []))
    held = list((g.attrs.get("splits") or {}).get("heldout", []))
    done = np.asarray(g["done"][:]) if "done" in g else np.ones(g["pose"].shape[0], dtype=bool)
    clip_id = np.asarray(g["clip_id"][:])
    held_ids = [clip_names.index(c) for c in held if c in clip_names]
    rows = np.flatnonzero(np.isin(clip_id, held_ids) & done)
    if rows.size == 0:
        rows = np.flatnonzero(done)[-n_max:]
    check(rows.size > 0, f"{path}: no finished frames to check parity on")
    rows = rows[np.linspace(0, rows.size - 1, min(n_max, rows.size)).round().astype(int)]
    rows = np.unique(rows)
    return {"pose": np.asarray(g["pose"].get_orthogonal_selection((rows, slice(None))), dtype=np.float32),
            "frames": np.asarray(g["frames"].get_orthogonal_selection((rows,)), dtype=np.float32),
            "positions": np.asarray(g["positions"].get_orthogonal_selection((rows,)), dtype=np.float32),
            "rows": rows}


def write_frame_data(run_dir: Path) -> Path:
    """Copy the dataset's ``cluster (V,)``, ``cluster_axis (Kc, 3)``, ``cluster_bone (Kc,)`` to
    ``run_dir/frames.npz`` (atomically): the player rebuilds the local vertex frames from them."""
    import zarr

    from prt_torch.io import atomic_path

    g = zarr.open_group(str(run_dir / "dataset.zarr"), mode="r")
    missing = [k for k in ("cluster", "cluster_axis", "cluster_bone") if k not in g]
    check(not missing, f"{run_dir / 'dataset.zarr'}: missing frame data {missing} (re-bake the dataset)")
    out = run_dir / "frames.npz"
    with atomic_path(out) as tmp:
        with open(tmp, "wb") as f:
            np.savez(f, cluster=np.asarray(g["cluster"][:], dtype=np.int32),
                     cluster_axis=np.asarray(g["cluster_axis"][:], dtype=np.float32),
                     cluster_bone=np.asarray(g["cluster_bone"][:], dtype=np.int32))
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


def export_run(run_dir: str | os.PathLike[str], kind: str | None = None, brdfs: tuple[str, ...] = DEFAULT_BRDFS,
               n_terms: int = 8, opset: int = 17, exporter: str = "torchscript", force: bool = False,
               console: Any = None) -> dict[str, Any]:
    """Export a trained run to ONNX; returns the ``export.json`` content.

    Args:
        run_dir: ``runs/NAME`` holding ``model.pt`` (or ``models/<kind>.pt``), ``character.npz`` and
            ``dataset.zarr`` (for the held-out parity check).
        kind: model kind (``None``: the run's default model).
        brdfs: named BRDFs to turn into RPO files (order of the model, ``n_terms`` terms).
        n_terms: BRDF terms ``k`` of the shading graph (RPOs with fewer terms are zero-padded at run time).
        opset: ONNX opset (>= 17).
        exporter: ``"torchscript"`` or ``"dynamo"``.
        force: re-export even when ``export.json`` matches the model file.
    """
    import torch

    from prt_torch.export.graphs import (
        FUSED_INPUTS,
        SHADING_INPUTS,
        FusedGraph,
        ShadingGraph,
        VisibilityGraph,
    )
    from prt_torch.export.onnx_file import export_onnx, initializer_bytes
    from prt_torch.export.parity import check_parity
    from prt_torch.models.visibility import load_model, model_path
    from prt_torch.rig.character import Character

    run_dir = Path(run_dir)
    check(run_dir.is_dir(), f"run directory not found: {run_dir}")
    mpath = model_path(run_dir, kind)
    model = load_model(run_dir, kind)
    model_hash = _sha256_file(mpath)
    meta_path = run_dir / EXPORT_JSON
    if not force and meta_path.is_file():
        old = json.loads(meta_path.read_text())
        files = [run_dir / old.get("files", {}).get(k, "-") for k in ("visibility", "shading", "fused")]
        if (old.get("model_sha256") == model_hash and old.get("n_terms") == n_terms and old.get("opset") == opset
                and all(f.is_file() for f in files) and sorted(old.get("brdfs", [])) == sorted(brdfs)):
            return old
    char_path = run_dir / "character.npz"
    character = Character.load(char_path)
    check(character.num_vertices == model.n_vertices,
          f"model has {model.n_vertices} vertices but {char_path} has {character.num_vertices}")
    check(character.feature_width == model.n_features,
          f"model takes {model.n_features} pose features but the character gives {character.feature_width}")
    order, V, A, C = model.order, model.n_vertices, model.n_features, model.n_coeffs
    held = heldout_inputs(run_dir)
    write_frame_data(run_dir)
    check(held["frames"].shape[1] == V, f"dataset has {held['frames'].shape[1]} vertices, the model {V}")
    rpos = build_rpos(brdfs, order, n_terms)
    rpo_files = {}
    for name, rpo in rpos.items():
        rel = f"{RPO_DIR}/{name}.npz"
        rpo.save(run_dir / rel)
        rpo_files[name] = rel

    base_meta = {
        "prt.format": FORMAT, "prt.conventions": CONVENTIONS, "prt.sh_order": order, "prt.n_coeffs": C,
        "prt.n_vertices": V, "prt.n_features": A, "prt.n_terms": n_terms, "prt.model_kind": model.kind,
        "prt.character_hash": character.content_hash(), "prt.character_name": character.name,
        "prt.model_sha256": model_hash,
        "prt.frames": "frames input (B, 9, V): entry 3i+j = F[i, j], rows (t, b, n), world; local = F @ w",
        "prt.view_dirs": "(B, 3, V) unit world directions vertex -> eye",
    }
    batch = {0: "B"}
    vis_graph = VisibilityGraph(model).eval()
    shade_graph = ShadingGraph(order, n_terms).eval()
    fused_graph = FusedGraph(vis_graph, order, n_terms).eval()

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
    dyn_shade = {"visibility": batch, "frames": batch, "view_dirs": batch, "radiance": batch}
    dyn_fused = {"pose": batch, "frames": batch, "view_dirs": batch, "radiance": batch}
    t0 = time.perf_counter()
    parity: dict[str, Any] = {}
    specs = [("visibility", VISIBILITY_FILE, vis_graph, {"pose": pose}, ("pose",), ("visibility",),
              {"pose": batch, "visibility": batch}),
             ("shading", SHADING_FILE, shade_graph, shade_in, SHADING_INPUTS, ("radiance",), dyn_shade),
             ("fused", FUSED_FILE, fused_graph, fused_in, FUSED_INPUTS, ("radiance",), dyn_fused)]
    for graph_name, fname, module, inputs, in_names, out_names, dyn in specs:
        path = run_dir / fname
        args = [torch.from_numpy(np.ascontiguousarray(inputs[k], dtype=np.float32)) for k in in_names]
        export_onnx(module, args, path, in_names, out_names, dyn, metadata={**base_meta, "prt.graph": graph_name},
                    opset=opset, exporter=exporter)
        p = check_parity(module, path, {k: inputs[k] for k in in_names})
        parity[graph_name] = {**p.as_dict(), "initializer_bytes": initializer_bytes(path),
                              "file_bytes": path.stat().st_size}
        if console is not None:
            console.print(f"  {fname}: parity rel. error {p.rel_error:.2e} on {len(pose)} held-out poses")
    meta = {
        "format": FORMAT, "conventions": CONVENTIONS, "sh_order": order, "n_coeffs": C, "n_vertices": V,
        "n_features": A, "n_terms": n_terms, "model_kind": model.kind, "model_sha256": model_hash, "opset": opset,
        "exporter": exporter, "character_hash": character.content_hash(), "character_name": character.name,
        "character_file": "character.npz", "frames_file": "frames.npz",
        "files": {"visibility": VISIBILITY_FILE, "shading": SHADING_FILE, "fused": FUSED_FILE},
        "inputs": {"visibility": ["pose"], "shading": list(SHADING_INPUTS), "fused": list(FUSED_INPUTS)},
        "brdfs": sorted(rpo_files), "rpo_files": rpo_files, "parity": parity,
        "parity_rows": held["rows"].tolist(), "export_seconds": time.perf_counter() - t0,
    }
    atomic_write_json(meta_path, meta)
    return meta


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

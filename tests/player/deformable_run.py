"""A small exported DEFORMABLE run for the cloth player's tests (tests/player, tests/export): a waving 16 x 12 flag
(192 vertices), positions analytic per frame, ``pose`` = :func:`prt_torch.cloth.inputs.cloth_features`, frames =
:class:`prt_torch.deform.frames.FrameOperator` (the bake's rule), a synthetic visibility that is a smooth non-linear
function of the dihedral angles, trained (linear + MLP, small) and exported with the deformable extras.

Built once per session (a marker file, like tests/export/pipeline.py); no simulation, no Embree: the run-time path
is what is tested, not the bake.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

NX, NZ, FRAMES, N_CLIPS, ORDER = 16, 12, 24, 5, 3


def flag_mesh(nx: int = NX, nz: int = NZ, size: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """``(rest (V, 3) float32, faces (T, 3) int64)``: a grid in the x-z plane, consistent orientation."""
    x, z = np.meshgrid(np.linspace(0, 1.4 * size, nx), np.linspace(0, size, nz), indexing="ij")
    rest = np.stack([x.ravel(), np.zeros(x.size), z.ravel()], 1).astype(np.float32)
    idx = np.arange(nx * nz).reshape(nx, nz)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    faces = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)]).astype(np.int64)
    return rest, faces


def flag_positions(rest: np.ndarray, n_frames: int, seed: int) -> np.ndarray:
    """``(T, V, 3)`` float32: travelling waves along the flag, pinned at x = 0 (a wind pattern per seed)."""
    rng = np.random.default_rng(seed)
    x, z = rest[:, 0].astype(np.float64), rest[:, 2].astype(np.float64)
    t = np.arange(n_frames)[:, None] / 12.0
    k, w, ph = rng.uniform(3, 6), rng.uniform(4, 8), rng.uniform(0, 2 * np.pi)
    k2, ph2, amp = rng.uniform(2, 5), rng.uniform(0, 2 * np.pi), rng.uniform(0.08, 0.16)
    y = amp * x[None] * (np.sin(k * x[None] - w * t + ph) + 0.5 * np.sin(k2 * z[None] + 0.7 * w * t + ph2))
    pos = np.repeat(rest[None].astype(np.float64), n_frames, 0)
    pos[..., 1] = y
    pos[..., 0] -= 0.15 * amp * x[None] * (1 + np.cos(k * x[None] - w * t))  # some in-plane shortening
    return pos.astype(np.float32)


def flag_character(rest: np.ndarray, faces: np.ndarray) -> object:
    """The single-root-joint subject (all skin weights 1 on the root), as the cloth runs save it."""
    from prt_torch.rig.character import Character
    from prt_torch.rig.mesh import vertex_normals

    v = rest.shape[0]
    eye = np.eye(4)[None]
    return Character(name="testflag", joint_names=["root"], parents=np.array([-1], np.int64), bind_local=eye.copy(),
                     inverse_bind=eye.copy(), rest_vertices=rest, rest_normals=vertex_normals(rest, faces),
                     faces=faces, joints=np.zeros((v, 1), np.int64), weights=np.ones((v, 1), np.float32))


def build_deformable_run(base: Path, nx: int = NX, nz: int = NZ, order: int = ORDER, name: str = "deformable_run",
                         neurons: int = 8, n_body: int = 0) -> tuple[Path, object]:
    """Write, train and export the run into ``base/<name>`` (once); returns ``(run_dir, DeformSpec)``.
    ``nx * nz`` vertices (the default 192; 110 x 70 = 7.7k is the issue's flag size, for benchmarks). ``n_body``:
    that many body features appended to the dihedral angles (the cape's ``append_pose``: :func:`body_features`), and
    the visibility depends on them too."""
    import zarr

    from prt_torch.bake.deformable import frame_operator
    from prt_torch.cloth.export import DeformSpec
    from prt_torch.cloth.inputs import cloth_features
    from prt_torch.deform.clusters import spatial_clusters
    from prt_torch.deform.mesh import interior_edges
    from prt_torch.fit.config import TrainConfig
    from prt_torch.fit.train import train_dataset
    from prt_torch.rig.vertex_frames import cluster_axes
    from prt_torch.sh.basis import sh_basis

    run_dir = base / name
    rest, faces = flag_mesh(nx, nz)
    ch = flag_character(rest, faces)
    labels = np.asarray(spatial_clusters(rest, 6, 0), np.int32)
    op = frame_operator(ch, labels)
    edges = np.asarray(interior_edges(faces), np.int64)
    spec = DeformSpec(edges=edges, cloth_slice=slice(0, rest.shape[0]), n_body_features=n_body, operator=op)
    marker = base / f"{name}.done"
    if marker.is_file():
        return run_dir, spec
    run_dir.mkdir(parents=True, exist_ok=True)
    ch.save(run_dir / "character.npz")
    clips = [f"wind{k}" for k in range(N_CLIPS - 1)] + ["wind_heldout"]
    pos = np.concatenate([flag_positions(rest, FRAMES, seed=k) for k in range(N_CLIPS)])
    body = np.concatenate([body_features(FRAMES, n_body, seed=k) for k in range(N_CLIPS)]) if n_body else None
    pose = np.asarray(cloth_features(pos, edges, body), np.float32)
    frames = np.asarray(op.frames(pos), np.float32)
    # visibility: hemisphere SH + occluders whose strength is a smooth step of the local fold (dihedral angles)
    rng = np.random.default_rng(1)
    v = rest.shape[0]
    d = rng.normal(size=(4096, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    h = (sh_basis(d, order) * (d[:, 2:3] > 0)).mean(0) * 4 * np.pi
    u = rng.normal(size=(edges.shape[0], 8)) / np.sqrt(edges.shape[0]) * 2.0
    w = rng.normal(size=(8, v)) * 3.0
    occ = rng.normal(size=(v, 3))
    occ[:, 2] = np.abs(occ[:, 2]) + 0.5
    occ /= np.linalg.norm(occ, axis=1, keepdims=True)
    o = -0.6 * sh_basis(occ, order)
    logit = np.tanh(pose[:, :edges.shape[0]].astype(np.float64) @ u) @ w
    if n_body:  # the body's pose shadows the cloth too
        logit = logit + np.sin(body.astype(np.float64) @ rng.normal(size=(n_body, v)))
    s = 1.0 / (1.0 + np.exp(-4.0 * logit))
    vis = (h[None, None] + s[..., None] * o[None]).astype(np.float32)
    n = pos.shape[0]
    g = zarr.open_group(str(run_dir / "dataset.zarr"), mode="w")
    for name, arr in (("pose", pose), ("visibility", vis), ("positions", pos), ("normals", frames[:, :, 2]),
                      ("frames", frames)):
        g.create_array(name, data=np.ascontiguousarray(arr), chunks=(8,) + arr.shape[1:])
    g.create_array("clip_id", data=np.repeat(np.arange(N_CLIPS), FRAMES).astype(np.int32), chunks=(8,))
    g.create_array("frame_index", data=np.tile(np.arange(FRAMES), N_CLIPS).astype(np.int32), chunks=(8,))
    g.create_array("done", data=np.ones(n, dtype=bool), chunks=(8,))
    g.create_array("faces", data=faces.astype(np.int32))
    g.create_array("cluster", data=labels)
    g.create_array("cluster_axis", data=np.asarray(cluster_axes(rest, labels), np.float32))
    g.create_array("cluster_bone", data=np.zeros(int(labels.max()) + 1, np.int32))
    g.attrs.update({"clip_names": clips, "splits": {"train": clips[:-1], "heldout": clips[-1:]},
                    "character_hash": ch.content_hash(), "sh_order": order, "n_rays": 0, "conventions": "synthetic",
                    "versions": {}, "config": {}, "deformable": True})
    train_dataset(run_dir / "dataset.zarr", run_dir,
                  TrainConfig(kinds=["linear", "mlp"], default_kind="mlp", alphas=[1.0], mlp_alphas=[1.0],
                              neurons=[neurons], cv_iter=30, max_iter=80, folds=2))
    from prt_torch.export.run import export_run

    export_run(run_dir, brdfs=("lambert", "phong"), deform=spec)
    marker.write_text("ok\n")
    return run_dir, spec


def body_features(n_frames: int, n_body: int, seed: int) -> np.ndarray:
    """``(n_frames, n_body)`` smooth per-clip body features (sines of time with seeded rates and phases)."""
    rng = np.random.default_rng(100 + seed)
    t = np.arange(n_frames)[:, None] / FRAMES
    return np.sin(2 * np.pi * rng.uniform(0.3, 1.5, n_body) * t + rng.uniform(0, 2 * np.pi, n_body)).astype(np.float32)


def heldout_positions(n_frames: int = FRAMES) -> np.ndarray:
    """The held-out clip's positions (the last wind pattern)."""
    rest, _ = flag_mesh()
    return flag_positions(rest, n_frames, seed=N_CLIPS - 1)

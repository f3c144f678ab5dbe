"""Session fixtures of trained runs.

* ``synthetic_dataset``: a small dataset.zarr in the documented layout whose visibility is a known
  smooth-step (non-linear) function of the pose; used where the real bake is not needed.
* ``small_run``: a run trained (all three kinds, small CV grid, < ~1 min) on the bake helper's
  ``small_dataset`` (tests/fixtures_bake.py); falls back to ``synthetic_dataset`` only while that
  fixture does not exist. Returns the run directory (``model.pt``, ``models/<kind>.pt``,
  ``model.json``, ``metrics.json``).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

SMALL_TRAIN = dict(kinds=["linear", "quadratic", "mlp"], alphas=[1e-2, 1.0, 100.0], mlp_alphas=[1.0, 10.0],
                   neurons=[8], cv_iter=60, max_iter=200, folds=4)


def write_synthetic_dataset(path: Path, n_vertices: int = 240, order: int = 3, seed: int = 0,
                            frames_per_clip: int = 48) -> Path:
    """Write a synthetic dataset.zarr: 4 training clips + 1 held-out clip, 8 clusters.

    ``visibility[f, v] = h + sum_j o_vj * sigmoid(8 (pose_f . u_{c(v) j} - t_vj))`` with ``h``
    the SH of the upper-hemisphere indicator, so the truth is a smoothed step of the pose.
    """
    import zarr

    from prt_torch.sh.basis import sh_basis

    rng = np.random.default_rng(seed)
    c = order * order
    n_feat, n_lat, n_clusters, n_occ = 12, 4, 8, 2
    mix = rng.normal(size=(n_lat, n_feat)) / np.sqrt(n_lat)
    clips, poses, clip_ids, fidx = [], [], [], []
    for k in range(5):
        t = np.arange(frames_per_clip) / 30.0
        freq = rng.uniform(0.5, 1.5, n_lat)
        phase = rng.uniform(0, 2 * np.pi, n_lat)
        lat = np.sin(2 * np.pi * freq[None] * t[:, None] + phase[None])
        poses.append(lat @ mix + 0.01 * rng.normal(size=(len(t), n_feat)))
        clip_ids.append(np.full(len(t), k))
        fidx.append(np.arange(len(t)))
        clips.append(f"clip{k}" if k < 4 else "heldout0")
    pose = np.concatenate(poses).astype(np.float32)
    clip_id = np.concatenate(clip_ids).astype(np.int32)
    frame_index = np.concatenate(fidx).astype(np.int32)
    # geometry: points on a sphere, clusters by azimuth sector
    d = rng.normal(size=(n_vertices, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    cluster = (((np.arctan2(d[:, 1], d[:, 0]) + np.pi) / (2 * np.pi) * n_clusters).astype(np.int32)) % n_clusters
    mu = np.linspace(0, 1, 64)
    hemi_dirs = rng.normal(size=(4096, 3))
    hemi_dirs /= np.linalg.norm(hemi_dirs, axis=1, keepdims=True)
    y = sh_basis(hemi_dirs, order)
    h = (y * (hemi_dirs[:, 2:3] > 0)).mean(0) * 4 * np.pi  # SH of the hemisphere indicator (MC)
    del mu
    u = rng.normal(size=(n_clusters, n_occ, n_feat)) / np.sqrt(n_feat) * 2.0
    thr = 0.3 * rng.normal(size=(n_vertices, n_occ))
    occ_dirs = rng.normal(size=(n_vertices, n_occ, 3))
    occ_dirs[..., 2] = np.abs(occ_dirs[..., 2])
    occ_dirs /= np.linalg.norm(occ_dirs, axis=-1, keepdims=True)
    o = -0.8 * sh_basis(occ_dirs.reshape(-1, 3), order).reshape(n_vertices, n_occ, c)
    proj = np.einsum("fa,vja->fvj", pose.astype(np.float64), u[cluster])
    s = 1.0 / (1.0 + np.exp(-8.0 * (proj - thr[None])))
    vis = (h[None, None] + np.einsum("fvj,vjc->fvc", s, o)).astype(np.float32)
    n_frames = pose.shape[0]
    positions = np.broadcast_to(d[None], (n_frames, n_vertices, 3)).astype(np.float32)
    t_axis = np.cross(d, np.array([0.0, 0.0, 1.0]) + 1e-3)
    t_axis /= np.linalg.norm(t_axis, axis=1, keepdims=True)
    frames = np.stack([t_axis, np.cross(d, t_axis), d], axis=1)
    g = zarr.open_group(str(path), mode="w")
    g.create_array("pose", data=pose, chunks=(8, n_feat))
    g.create_array("visibility", data=vis, chunks=(8, n_vertices, c))
    g.create_array("positions", data=positions, chunks=(8, n_vertices, 3))
    g.create_array("normals", data=positions.copy(), chunks=(8, n_vertices, 3))
    g.create_array("frames", data=np.broadcast_to(frames[None], (n_frames, n_vertices, 3, 3)).astype(np.float32),
                   chunks=(8, n_vertices, 3, 3))
    g.create_array("clip_id", data=clip_id, chunks=(8,))
    g.create_array("frame_index", data=frame_index, chunks=(8,))
    g.create_array("done", data=np.ones(n_frames, dtype=bool), chunks=(8,))
    g.create_array("faces", data=np.zeros((0, 3), np.int32))
    g.create_array("cluster", data=cluster)
    g.attrs.update({"clip_names": clips, "splits": {"train": clips[:4], "heldout": clips[4:]},
                    "character_hash": "synthetic", "sh_order": order, "n_rays": 0, "conventions": "synthetic",
                    "versions": {}, "config": {}})
    return path


@pytest.fixture(scope="session")
def synthetic_dataset(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Path of a synthetic dataset.zarr (see :func:`write_synthetic_dataset`)."""
    return write_synthetic_dataset(tmp_path_factory.mktemp("synthetic") / "dataset.zarr")


@pytest.fixture(scope="session")
def small_run(request: pytest.FixtureRequest, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Run directory trained on ``small_dataset`` (all three kinds, small CV grid)."""
    from prt_torch.fit.config import TrainConfig
    from prt_torch.fit.train import train_dataset

    try:
        dataset = Path(request.getfixturevalue("small_dataset"))
    except pytest.FixtureLookupError:
        dataset = Path(request.getfixturevalue("synthetic_dataset"))
    run_dir = tmp_path_factory.mktemp("small_run")
    train_dataset(dataset, run_dir, TrainConfig(**SMALL_TRAIN))
    return run_dir

"""The ``train.s001`` stage: seed 001's compressed per-pose transfer matrices (sections 2-4) -> ``s001.npz``.

Input: the store's ``transfer_matrix (F, V, C, C)`` (local-frame rows, global light columns; ``bake.transfer_matrix``)
at the rows of clip ``train.s001.clip`` (``"random"``: the ``character.random_mode: cpca`` sampled poses, seed 001
sec. 2), and their pose features.

1. Segments (sec. 2): the skinning clusters (the store's ``cluster``), consistent across poses by construction.
2. Mesh segment clustering (sec. 3): per segment, recursive normalized cut of its ``P`` posed copies into groups of
   ``leaf_size`` poses, eq. 3 weights from the summed transfer-matrix distances and the bone transforms (the 6D
   rotation features of every non-root joint stand for ``R_b``): :func:`prt_torch.s001.ncut.cluster_segments`,
   which streams the store in vertex blocks.
3. Segment-relative matrices: ``T_k = T D(R_k)`` (:class:`prt_torch.s001.posespace.CompressedTransfer`), the
   segment rotations from the stored vertex frames; steps 2 and 4 read the store through :class:`RowStream`.
   Clustered PCA (sec. 4) with the paper's row constraint: every row of corresponding vertices of one pose group
   (``|g|`` matrices) belongs to ONE PCA cluster (so eq. 7 interpolates scalar coefficients). ``cpca: segment``
   (default): per segment, ``clusters_per_segment`` clusters of ``n_basis`` basis matrices (+ mean), initialised by
   k-means of the row means, ``cpca_iters`` rounds of (PCA, reassign each row to the cluster of least summed squared
   error); segments streamed in batches that fit ``memory_mb`` (one pass over the store per batch).
   ``cpca: revised``: section 4's incremental algorithm (:class:`prt_torch.s001.rcpca.RevisedCPCA`, per-pose
   budget ``m_cpf``, reclustering, merging), which streams one pose at a time. The clusters used per pose are
   reported (``clusters_per_pose_max``).
4. 16-bit coefficients per PCA cluster and basis (:func:`prt_torch.s001.quantize.quantize16`).
5. Run-time data (:class:`prt_torch.s001.posespace.CompressedTransfer`): the sampled poses' features, the eq. 6
   per-segment bone weights (:func:`prt_torch.s001.posespace.segment_bone_weights`), the groups, the clusters.

Resumable: ``s001.npz`` records the stage key (settings + the store's key); a current file is kept.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

import numpy as np

from prt_torch.bake.store import BakedDataset
from prt_torch.errors import DamagedArtifact, PrtError, StaleArtifact, check
from prt_torch.fit.config import S001Config, TrainConfig
from prt_torch.fit.stages import FitHook
from prt_torch.rundir import RunDir, stage_key
from prt_torch.s001.posespace import CompressedTransfer, segment_bone_weights

ARRAY = "transfer_matrix"


class RowStream:
    """A ``(P, V, C, C)`` view of the store's ``transfer_matrix`` at dataset ``rows`` with basic slicing
    (``stream[:, v0:v1]``), as :func:`prt_torch.s001.ncut.segment_sq_dists_streamed` reads it."""

    def __init__(self, ds: BakedDataset, rows: np.ndarray, rot: np.ndarray | None = None,
                 segment: np.ndarray | None = None, name: str = ARRAY) -> None:
        self.ds, self.rows, self.name = ds, np.asarray(rows, np.int64), name
        self.rot, self.segment = rot, segment  # (P, K, C, C) D(R_k) per row: read T D(R_k) (segment-relative)
        a = ds.array(name)
        self.shape = (len(self.rows), *a.shape[1:])

    def __getitem__(self, key: Any) -> np.ndarray:
        if isinstance(key, (int, np.integer)):  # one sampled pose (V, C, C), as RevisedCPCA reads it
            return self.read((slice(None), slice(None), slice(None)), rows=np.array([int(key)]))[0]
        key = key if isinstance(key, tuple) else (key,)
        check(len(key) >= 1 and key[0] == slice(None), "RowStream: only [j] and [:, ...] selections")
        rest = tuple(key[1:]) + (slice(None),) * (len(self.shape) - len(key))
        return self.read(rest)

    def read(self, rest: tuple[Any, ...], batch: int = 64, rows: np.ndarray | None = None) -> np.ndarray:
        """The sampled poses ``rows`` (default: all) at the vertex selection ``rest`` (float32), ``batch`` rows
        per read."""
        a = self.ds.array(self.name)
        sel = np.arange(len(self.rows)) if rows is None else np.asarray(rows)
        parts = [np.asarray(a.get_orthogonal_selection((self.rows[sel[i:i + batch]],) + rest), np.float32)
                 for i in range(0, len(sel), batch)]
        out = np.concatenate(parts, axis=0)
        if not np.isfinite(out).all():
            raise PrtError(f"{self.ds.path}: {self.name} contains NaN or inf at the s001 rows")
        if self.rot is not None:
            seg = self.segment[rest[0]]
            out = np.einsum("pvij,pvjk->pvik", out, self.rot[sel][:, seg], dtype=np.float32, optimize=True)
        return out


def _pca(x: np.ndarray, nb: int) -> tuple[np.ndarray, np.ndarray]:
    """Mean ``(D,)`` and the top ``nb`` principal directions ``(nb, D)`` (zero rows past the rank) of ``x (n, D)``."""
    mean = x.mean(axis=0)
    xc = (x - mean).astype(np.float64)
    cov = xc.T @ xc
    w, u = np.linalg.eigh(cov)
    top = u[:, ::-1][:, :nb].T
    top[np.arange(min(nb, len(w))) >= min(len(x), len(w))] = 0.0
    out = np.zeros((nb, x.shape[1]))
    out[:len(top)] = top
    return mean.astype(np.float32), out.astype(np.float32)


def cpca_segment(x: np.ndarray, groups: np.ndarray, n_clusters: int, nb: int, iters: int,
                 seed: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Row-constrained CPCA of one segment (module doc, step 3).

    Args:
        x: ``(P, Vk, D)`` float32 transfer matrices of the segment's vertices at the sampled poses.
        groups: ``(P,)`` pose group of each pose (``0..G-1``).
    Returns:
        ``row_cluster (G, Vk)`` int, ``mean (m, D)``, ``basis (m, nb, D)``, ``coeffs (P, Vk, nb)`` float32.
    """
    from sklearn.cluster import KMeans

    p, vk, d = x.shape
    n_groups = int(groups.max()) + 1
    count = np.bincount(groups, minlength=n_groups).astype(np.float32)
    row_mean = np.zeros((n_groups, vk, d), np.float32)
    np.add.at(row_mean, groups, x)
    row_mean /= count[:, None, None]
    m = int(min(n_clusters, n_groups * vk))
    km = KMeans(n_clusters=m, n_init=1, random_state=seed, max_iter=50).fit(row_mean.reshape(-1, d))
    row = km.labels_.reshape(n_groups, vk)
    for it in range(iters + 1):
        used = np.unique(row)
        row = np.searchsorted(used, row)  # drop empty clusters
        member = row[groups]  # (P, Vk) cluster of each (pose, vertex)
        means, bases = zip(*[_pca(x[member == c], nb) for c in range(len(used))], strict=True)
        mean, basis = np.stack(means), np.stack(bases)
        if it == iters:
            break
        # summed squared residual of every row under every cluster: ||x - m||^2 - ||U (x - m)||^2 from one product
        # of the samples with all means and bases, in blocks of poses
        m2 = np.einsum("md,md->m", mean, mean)
        um = np.einsum("mbd,md->mb", basis, mean)
        stack = np.concatenate([mean[:, None], basis], axis=1).reshape(-1, d)  # (m (nb + 1), D)
        err = np.zeros((n_groups, vk, len(used)))
        step = max(1, (1 << 22) // max(1, vk * len(stack)))
        for p0 in range(0, p, step):
            xs = x[p0:p0 + step]
            pr = (xs @ stack.T).reshape(len(xs), vk, len(used), nb + 1)
            x2 = np.einsum("pvd,pvd->pv", xs, xs)
            res = x2[..., None] - 2 * pr[..., 0] + m2 - np.einsum("pvmb,pvmb->pvm", pr[..., 1:] - um, pr[..., 1:] - um)
            np.add.at(err, groups[p0:p0 + step], res)
        row = np.argmin(err, axis=-1)
    member = row[groups]
    coeffs = np.zeros((p, vk, nb), np.float32)
    for c in range(len(mean)):  # per cluster: no (P, Vk, nb, D) gather of the bases
        sel = member == c
        coeffs[sel] = (x[sel] - mean[c]) @ basis[c].T
    return row, mean, basis, coeffs


def _segment_cpca(stream: RowStream, seg: np.ndarray, groups: np.ndarray, scfg: S001Config,
                  budget: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, float, float]:
    """``cpca: segment``: :func:`cpca_segment` per segment, segments streamed in batches that fit ``budget`` bytes
    (one pass over the store per batch). Returns ``vertex_cluster (G, V)``, ``mean (M, D)``, ``basis (M, nb, D)``,
    ``coeffs (P, V, nb)``, the summed squared error and the summed squares of the data."""
    p, v = stream.shape[:2]
    d = int(np.prod(stream.shape[2:]))
    nb, n_seg = scfg.n_basis, int(seg.max()) + 1
    vertex_cluster = np.zeros((int(groups.max()) + 1, v), np.int32)
    coeffs = np.zeros((p, v, nb), np.float32)
    means: list[np.ndarray] = []
    bases: list[np.ndarray] = []
    sse = sst = 0.0
    sizes = np.bincount(seg, minlength=n_seg)
    per_vertex = p * d * 4 * 3  # the data + working copies
    batch: list[int] = []
    batches: list[list[int]] = []
    for k in range(n_seg):
        if batch and (sum(sizes[batch]) + sizes[k]) * per_vertex > budget:
            batches.append(batch)
            batch = []
        batch.append(k)
    batches.append(batch)
    n_clusters = 0
    for bk in batches:
        verts = np.flatnonzero(np.isin(seg, bk))
        xb = stream.read((verts, slice(None), slice(None))).reshape(p, len(verts), d)
        for k in bk:
            sel = seg[verts] == k
            vk = verts[sel]
            x = xb[:, sel]
            row, mean, basis, ck = cpca_segment(x, groups[k], scfg.clusters_per_segment, nb, scfg.cpca_iters,
                                                scfg.seed)
            vertex_cluster[:row.shape[0], vk] = row + n_clusters
            vertex_cluster[row.shape[0]:, vk] = n_clusters  # unused groups of this segment
            coeffs[:, vk] = ck
            member = row[groups[k]]
            for c in range(len(mean)):
                sel = member == c
                sse += float(((mean[c] + ck[sel] @ basis[c] - x[sel]) ** 2).sum())
            sst += float((x**2).sum())
            means.append(mean)
            bases.append(basis)
            n_clusters += len(mean)
        del xb
    return vertex_cluster, np.concatenate(means), np.concatenate(bases), coeffs, sse, sst


def fit_s001(ds: BakedDataset, scfg: S001Config, skinning: tuple[np.ndarray, np.ndarray, np.ndarray],
             log: Callable[[str], None] = lambda s: None) -> CompressedTransfer:
    """Fit the compressed transfer matrices of a store (module doc); ``skinning = (parents, joints, weights)``."""
    from prt_torch.s001.ncut import cluster_segments
    from prt_torch.s001.quantize import quantize16

    check(ARRAY in ds, f"{ds.path}: no {ARRAY} array (bake with bake.transfer_matrix: true for train.s001)")
    check(scfg.clip in ds.clip_names, f"train.s001.clip {scfg.clip!r} is not a clip of {ds.path} "
                                      f"({', '.join(ds.clip_names)})")
    rows = ds.clip_rows(scfg.clip)
    check(len(rows) >= 2 * scfg.leaf_size, f"train.s001: clip {scfg.clip!r} has {len(rows)} baked poses, need at "
                                           f"least {2 * scfg.leaf_size} (2 x leaf_size)")
    t0 = time.perf_counter()
    parents, joints, weights = skinning
    poses = ds.pose[rows].astype(np.float32)
    p = len(rows)
    seg = np.asarray(ds.cluster, np.int64)
    n_seg = int(seg.max()) + 1
    v = len(seg)
    from prt_torch.s001.posespace import segment_rotations
    from prt_torch.sh.rotation import sh_rotation

    c = int(ds.array(ARRAY).shape[2])
    order = int(round(np.sqrt(c)))
    check(order * order == c and ds.array(ARRAY).shape[1:] == (v, c, c),
          f"{ds.path}: {ARRAY} must be (F, V, C, C), got {ds.array(ARRAY).shape}")
    ref = np.asarray(ds.rows(rows[:1], ("frames",))["frames"][0], np.float32)
    rot = np.empty((p, n_seg, c, c), np.float32)
    for i in range(0, p, 32):  # D(R_k) of every sampled pose (frames read in batches)
        fr = ds.rows(rows[i:i + 32], ("frames",))["frames"]
        rot[i:i + 32] = sh_rotation(segment_rotations(fr, ref, seg, n_seg), order)
    stream = RowStream(ds, rows, rot, seg)
    d = c * c
    feature_joints = np.flatnonzero(np.asarray(parents) >= 0)
    check(poses.shape[1] == 6 * len(feature_joints), f"{ds.path}: pose features ({poses.shape[1]}) do not match "
                                                     f"the character's {len(feature_joints)} non-root joints")
    jw = segment_bone_weights(seg, np.asarray(joints), np.asarray(weights), n_seg, feature_joints,
                              scfg.other_bone_weight).astype(np.float32)
    budget = scfg.memory_mb << 20
    block = int(max(1, min(v, budget // max(1, p * d * 8 * 2))))
    groups = cluster_segments(stream, seg, poses.reshape(p, -1, 6), scfg.leaf_size, scfg.t_scale, scfg.p_scale,
                              block=block)
    t_ncut = time.perf_counter() - t0
    log(f"s001: {n_seg} segments x {p} poses -> {int(groups.max()) + 1} groups max per segment "
        f"(normalized cut, {t_ncut:.1f} s)")
    nb = scfg.n_basis
    if scfg.cpca == "revised":
        from prt_torch.s001.rcpca import RevisedCPCA

        rc = RevisedCPCA(n_basis=nb, m_cpf=scfg.m_cpf, seed=scfg.seed, cache_bytes=budget // 2)
        rc.fit(stream, seg, groups)
        codes, scale, offset = rc.quantize()
        vertex_cluster = np.where(rc.unit_cluster_ >= 0, rc.unit_cluster_, 0).T.astype(np.int32)
        mean_all, basis_all = rc.means_.reshape(len(rc.means_), d), rc.bases_.reshape(len(rc.bases_), nb, d)
        sse, sst = rc.sse_, rc.total_sumsq_
        cpca_stats: dict[str, Any] = dict(rc.stats_)
    else:
        vertex_cluster, mean_all, basis_all, coeffs, sse, sst = _segment_cpca(stream, seg, groups, scfg, budget)
        cl = vertex_cluster[groups[seg, :].T, np.arange(v)]  # (P, V) cluster of every (pose, vertex)
        codes, scale, offset = quantize16(coeffs.reshape(-1, nb), cl.reshape(-1))
        cpca_stats = {}
    n_clusters = len(mean_all)
    t_cpca = time.perf_counter() - t0 - t_ncut
    cl = vertex_cluster[groups[seg, :].T, np.arange(v)]  # (P, V) cluster of every (pose, vertex)
    per_pose = np.array([len(np.unique(r)) for r in cl])
    raw = p * v * d * 4
    meta: dict[str, Any] = {
        "order": int(round(np.sqrt(c))), "n_poses": p, "n_vertices": v, "n_segments": n_seg,
        "n_clusters": int(n_clusters), "n_basis": nb, "scale": float(scfg.rbf_scale), "clip": scfg.clip,
        "raw_bytes": int(raw), "train_rel_err_unquantised": float(np.sqrt(sse / max(sst, 1e-30))),
        "clusters_per_pose_max": int(per_pose.max()), "clusters_per_pose_mean": float(per_pose.mean()),
        "group_size_max": int(max(np.bincount(g).max() for g in groups)),
        "seconds": {"ncut": t_ncut, "cpca": t_cpca}, "cpca": scfg.cpca, "m_cpf": scfg.m_cpf, "cpca_stats": cpca_stats,
    }
    data = CompressedTransfer(
        poses=poses, joint_weights=jw, groups=groups.astype(np.int16), segment=seg.astype(np.int32),
        vertex_cluster=vertex_cluster, mean=mean_all, basis=basis_all, coeff_q=codes.reshape(p, v, nb),
        coeff_offset=offset, coeff_scale=scale, ref_frames=ref, meta=meta)
    meta["stored_bytes"] = data.stored_bytes()
    meta["compression_ratio"] = raw / data.stored_bytes()
    meta["seconds"]["total"] = time.perf_counter() - t0
    log(f"s001: {n_clusters} PCA clusters x {nb} basis, train rel err {meta['train_rel_err_unquantised']:.4f}, "
        f"compression {meta['compression_ratio']:.1f}x ({raw / 1e6:.1f} MB -> {data.stored_bytes() / 1e6:.2f} MB)")
    return data


def s001_key(ds: BakedDataset, scfg: S001Config) -> str:
    return stage_key({"s001": scfg.model_dump(mode="json"), "dataset": ds.key()})


def train_s001(ds: BakedDataset, run: RunDir, cfg: TrainConfig, progress: Any = None) -> dict[str, Any] | None:
    """Run the stage when ``cfg.s001`` is set (a current ``s001.npz`` is kept); without it a stale ``s001.npz`` is
    removed. Returns the metadata (``None`` without ``train.s001``)."""
    path = run.s001
    if cfg.s001 is None:
        path.unlink(missing_ok=True)
        return None
    key = s001_key(ds, cfg.s001)
    if path.is_file():
        try:
            old = CompressedTransfer.load(path)
            if old.meta.get("key") == key:
                return old.meta
        except (StaleArtifact, DamagedArtifact):
            pass
    from prt_torch.fit.inputs import load_skinning

    def log(s: str) -> None:
        if progress is not None and hasattr(progress, "console"):
            progress.console.print(s)

    data = fit_s001(ds, cfg.s001, load_skinning(ds), log)
    data.meta["key"] = key
    data.save(path)
    return data.meta


#: the entries of ``s001.npz``'s metadata that ``metrics.json`` records under ``s001``
METRICS_KEYS = ("compression_ratio", "raw_bytes", "stored_bytes", "n_clusters", "train_rel_err_unquantised", "seconds")


def fit_stage(ds: BakedDataset, run: RunDir, cfg: TrainConfig, splits: dict[str, Any],
              progress: Any = None) -> dict[str, Any] | None:
    """The :class:`~prt_torch.fit.stages.FitHook` call: :func:`train_s001` (it streams the store itself:
    ``splits`` is not needed). Returns ``metrics.json``'s ``s001`` entry (:data:`METRICS_KEYS` of the metadata),
    ``None`` without ``train.s001``."""
    meta = train_s001(ds, run, cfg, progress)
    return None if meta is None else {k: meta[k] for k in METRICS_KEYS}


#: ``prt train``'s ``train.s001`` step (:data:`prt_torch.fit.stages.FIT_STAGES`)
FIT_HOOK = FitHook(section="s001", metrics_key="s001", run=fit_stage)

"""Seed 001's revised clustered PCA of transfer matrices (section 4), out of core.

Data layout (the paper's Fig. 2): the bake writes per frame (= sampled pose) ``transfer_matrix (V, C, C)``;
stacked over poses that is ``stream (P, V, C, C)`` (or ``(P, V, D)``). A SAMPLE is one vertex's transfer
matrix at one pose, flattened row-major to ``D = C^2`` float32 values (``T[c_out, c_in]``, local-frame
rows). The paper's data matrix has vertices as rows and poses as columns. After the consistent
segmentation (``segments (V,)``, the skinning clusters, ``n_r`` segments) and mesh segment clustering
(``groups (n_r, P)``: the ncut pose groups ``Omega_{k,g}`` of :func:`prt_torch.s001.ncut.cluster_segments`),
a UNIT ("row of corresponding vertices" in the paper) is ``(v, g)``: vertex ``v``'s transfer matrices at
the poses of group ``g`` of its segment (``~leaf_size`` samples). Every sample of a unit belongs to the
same PCA cluster (the paper's second requirement), so run-time interpolation (eq. 7) mixes coefficients
of one basis. A PCA cluster has a mean and ``n_basis`` (8) orthonormal basis vectors ("basis matrices").

Algorithm (section 4), poses visited in order ``j = 0 .. P-1``:

* ``rho`` = fraction of pose ``j``'s vertices whose unit ``(v, groups[seg v, j])`` already has a cluster;
  ``E_j`` = the clusters they use. If ``1 - rho <= r (m_cpf - |E_j|) / m_cpf`` (``r = 2``): INCREMENTAL
  step (4.1): ``m_cpf - |E_j|`` new clusters; the unassigned units go to a new cluster or to one in
  ``E_j`` by the revised CPCA (assign each unit to the cluster of least summed squared error over its
  samples, refit the new clusters, repeat; existing members never move).
* otherwise RECLUSTERING (4.2): pose ``j``'s assigned units are removed from their clusters and all its
  units are clustered afresh by the original CPCA into ``m_cpf`` new clusters.
* MERGING (4.3): while some pose uses more than ``m_cpf`` clusters, merge the pair of minimal merge cost
  among the pairs used by one over-budget pose; clusters are merged without the raw data [HMM00].
  DEVIATION (default ``merge_cost="residual"``): the cost of merging ``a`` and ``b`` is the increase of the
  truncated residual energy ``E(a + b) - E(a) - E(b)`` (``E`` = scatter trace minus the top ``n_basis``
  eigenvalues = the squared error of projecting the members onto the cluster's basis), computed exactly from
  the two eigenspace models (:meth:`RevisedCPCA._residual_increase`): greedy merging then adds the least
  squared error per merge, the quantity CPCA minimises. The paper's eq. 4 ``d = ||P_a - P_b||_2 + eta
  ||M_a - M_b||`` (``P = U U^T``, residue ``M = m - P m``) is kept as ``merge_cost="eq4"``. Why: the
  sine of the largest principal angle between two 8-dim bases is ~1 for almost every pair as soon as one
  basis direction differs (noise directions of rank < 8 data, or clusters that merge different
  structures), so eq. 4 ranks pairs by the residue term alone, i.e. by mean distance, which says nothing
  about whether the union fits 8 basis vectors. Measured: (a) 12 planted rank-4 clusters whose pairs span
  one 8-dim affine subspace, budget 6 (test ``test_merging_pairs_clusters_whose_union_fits_the_basis``):
  eq. 4 3.9e4 x the noise floor, residual 1.04 x (exact planted pairs); (b) the ``/tmp/compress/bench.py
  syn 256 2000 16`` store (P 256 x V 2000 x D 256; its data has 48 planted rank-6 clusters, not the 12
  its label says: k-means inertia per vertex 143 at k = 12, 0.53 at k = 48 = the planted spread, so a
  budget of 16 per pose MUST merge different planted clusters): rel SSE 0.436 (eq. 4) -> 0.0109
  (residual), same ratio 59.0, fit 1123 s vs 414-541 s wall at load 3-7 (the batched ``(2q+1)^2``
  ``eigvalsh`` per candidate pair dominates). Where the budget suffices (12 planted rank-6 clusters,
  ``m_cpf`` 16) both reach the noise floor (64 x 480 x 64: 0.952 / 0.952; 256 x 2000 x 256: rel SSE 9.8e-5 /
  9.8e-5, 216 s / 630 s). Real store (runs/s001, 64 poses x 2000 vertices, m_cpf 64): 0.465 -> 0.0150.
  Option ``refit_before_merge`` (default off; a deviation from "without the raw data"): every cluster's
  model is rebuilt exactly from its members by one more stream before merging (the 4.2 downdates of
  truncated models drift; no measured gain: 0.951 vs 0.952).
  Fixed bug: the HMM merge built its span by QR without pivoting and dropped columns with small
  ``diag(R)``, which loses directions when an input is rank-deficient (one-sample models); now an SVD of
  the span (12 planted rank-6 clusters, P 64 x V 480 x D 64: rel SSE / noise floor 1.62 -> 0.95).
  eq. 4 options: ``projector_norm="fro"`` (Frobenius norm of ``P_a - P_b``); ``eta = 0`` gave 6e4 x floor.
* REFIT pass: every final cluster's mean and basis from its final members (second stream, per-pose
  models merged), then the FINAL pass: every sample's coefficients ``c = U (x - m)`` (third stream).

Out of core: a cluster is held as an eigenspace model (count, mean, top ``n_basis + extra`` eigenpairs
of its scatter, exact scatter trace), updated by Hall-Marshall-Martin merging (and the reverse,
downdating, for 4.2), never by its samples. ``stream`` needs only ``.shape`` and ``stream[j]`` (one pose,
``(V, ...)``); a zarr array is read one frame (chunk) at a time through a small LRU cache
(``cache_bytes``). Peak memory ~ cache + the units of one step (``~leaf_size`` poses x ``V`` x ``D``
float64) + cluster models (``K (n_basis + extra + 1) D`` float64) + the coefficients
(``P V n_basis`` float32, ``n_basis / D`` of the data).

Error accounting: ``sse_`` is the exact summed squared reconstruction error of the float coefficients
(measured in the final pass); ``sse_bound_`` sums each cluster's model residual ``trace - sum(top
n_basis eigenvalues)`` of the refitted models, which bounds the error of projecting the members onto
the basis (the models are built by merges only; truncated scatters are PSD-below the true one).
Stored bytes (:meth:`RevisedCPCA.nbytes`): coefficients as uint16 (per cluster and basis vector
scale/offset, :func:`prt_torch.s001.quantize.quantize16`), means+bases float32, unit table int32.
"""

from __future__ import annotations

import heapq
import math
import time
from collections import OrderedDict
from dataclasses import dataclass
from typing import Any

import numpy as np
import scipy.linalg

from prt_torch.errors import check
from prt_torch.s001.quantize import dequantize16, quantize16, quantized_nbytes


@dataclass
class _Eig:
    """Eigenspace model of a set of samples: ``n``, ``mean (D,)``, ``vecs (q, D)`` orthonormal rows,
    ``vals (q,)`` scatter eigenvalues (descending), ``trace`` = total scatter ``sum ||x - mean||^2``."""

    n: float
    mean: np.ndarray
    vecs: np.ndarray
    vals: np.ndarray
    trace: float


def _eig_from(x: np.ndarray, q: int) -> _Eig:
    """Model of the rows of ``x (n, D)`` (exact up to the truncation to ``q`` eigenpairs)."""
    n = x.shape[0]
    mean = x.mean(axis=0)
    xc = x - mean
    trace = float(np.einsum("ij,ij->", xc, xc))
    if n > x.shape[1]:
        d = x.shape[1]
        lam, vec = scipy.linalg.eigh(xc.T @ xc, subset_by_index=[max(0, d - q), d - 1], driver="evr")
        vals, vecs = lam[::-1], vec[:, ::-1].T
    else:
        _, s, vt = np.linalg.svd(xc, full_matrices=False)
        vals, vecs = (s ** 2)[:q], vt[:q]
    return _Eig(float(n), mean, np.ascontiguousarray(vecs), np.maximum(vals, 0.0), trace)


def _eig_combine(a: _Eig, b: _Eig, q: int, sign: float) -> _Eig | None:
    """``sign=+1``: model of the union of ``a`` and ``b`` [HMM00]; ``sign=-1``: ``a`` with ``b``'s samples removed.

    The scatter of the result is built in the span of ``[a.vecs, b.vecs, mean difference]`` and
    re-diagonalised: ``S = S_a + S_b + (n_a n_b / n) d d^T`` (merge) or ``S_a - S_b - (n n_b / n_a) d d^T``
    (downdate, negative eigenvalues clipped). Returns None when nothing is left.
    """
    n = a.n + sign * b.n
    if n <= 0.5:
        return None
    mean = (a.n * a.mean + sign * b.n * b.mean) / n
    if sign > 0:
        d, coef = a.mean - b.mean, a.n * b.n / n
    else:
        d, coef = mean - b.mean, n * b.n / a.n
    basis = np.concatenate([a.vecs, b.vecs, d[None]], axis=0).T
    # orthonormal span by SVD: QR without pivoting + dropping small diag(R) loses directions of rank-deficient
    # inputs (1-sample models), which left tiny merged clusters with wrong bases
    qm, sv, _ = np.linalg.svd(basis, full_matrices=False)
    keep = sv > 1e-10 * max(1.0, float(sv.max()))
    qm = qm[:, keep] if keep.any() else qm[:, :1]
    pa = qm.T @ a.vecs.T
    pb = qm.T @ b.vecs.T
    pd = qm.T @ d
    s = (pa * a.vals) @ pa.T + sign * ((pb * b.vals) @ pb.T + coef * np.outer(pd, pd))
    lam, vec = np.linalg.eigh((s + s.T) / 2)
    lam, vec = lam[::-1][:q], vec[:, ::-1][:, :q]
    trace = a.trace + sign * (b.trace + coef * float(d @ d))
    vals = np.maximum(lam, 0.0)
    return _Eig(n, mean, np.ascontiguousarray((qm @ vec).T), vals, max(trace, float(vals.sum())))


def _basis(m: _Eig, nb: int) -> np.ndarray:
    """``(nb, D)`` leading basis of a model, zero rows where it has fewer directions."""
    out = np.zeros((nb, m.mean.shape[0]))
    k = min(nb, m.vecs.shape[0])
    out[:k] = m.vecs[:k]
    return out


def _residual(m: _Eig, nb: int) -> float:
    return max(m.trace - float(m.vals[:nb].sum()), 0.0)


class _Frames:
    """``stream[j]`` as float64 ``(V, D)`` through an LRU cache of at most ``cap`` frames (NaN check on read)."""

    def __init__(self, stream: Any, v: int, d: int, cap: int) -> None:
        self.stream, self.v, self.d, self.cap = stream, v, d, max(1, cap)
        self.cache: OrderedDict[int, np.ndarray] = OrderedDict()
        self.reads = 0

    def __call__(self, j: int) -> np.ndarray:
        if j in self.cache:
            self.cache.move_to_end(j)
            return self.cache[j]
        x = np.asarray(self.stream[j], dtype=np.float64).reshape(self.v, self.d)
        check(bool(np.isfinite(x).all()), f"rcpca: transfer data of pose {j} contains NaN or Inf")
        self.reads += 1
        self.cache[j] = x
        while len(self.cache) > self.cap:
            self.cache.popitem(last=False)
        return x


@dataclass
class _Block:
    """Samples of a set of units, unit-major: ``x (S, D)``, ``ptr (U + 1,)`` offsets, ``verts (U,)``."""

    x: np.ndarray
    ptr: np.ndarray
    verts: np.ndarray

    @property
    def unit_of_sample(self) -> np.ndarray:
        return np.repeat(np.arange(self.verts.size), np.diff(self.ptr))


class RevisedCPCA:
    """Seed 001 section 4 (see the module docstring). Fit with :meth:`fit`; results end with ``_``.

    ``n_basis``: basis vectors per cluster (8); ``m_cpf``: per-pose cluster budget; ``r``: the ratio of
    the incremental/recluster criterion (2); ``eta``: eq. 4's residue weight (None: 1 / RMS sample norm,
    which makes both terms dimensionless); ``extra``: eigenpairs kept beyond ``n_basis`` in the cluster
    models (None: ``n_basis``); ``max_iter``: CPCA alternations per step (stopping early once at most
    ``tol`` of the units change cluster); ``cache_bytes``: frame cache; ``threads``: BLAS threads during
    :meth:`fit` (None: leave as is); ``projector_norm``: ``"2"`` (paper) or ``"fro"`` in eq. 4;
    ``refit_before_merge``: exact cluster models from their members before 4.3 (one more stream);
    ``merge_cost``: ``"residual"`` (increase of the truncated residual energy, default) or ``"eq4"`` (the
    paper's eq. 4 with ``projector_norm`` and ``eta``); see the module docstring for why and the numbers.
    """

    def __init__(self, n_basis: int = 8, m_cpf: int = 16, r: float = 2.0, eta: float | None = None,
                 extra: int | None = None, max_iter: int = 8, tol: float = 0.002, seed: int = 0,
                 cache_bytes: int = 64 << 20, threads: int | None = 1, projector_norm: str = "2",
                 refit_before_merge: bool = False, merge_cost: str = "residual") -> None:
        check(int(n_basis) >= 1, f"rcpca: n_basis must be >= 1, got {n_basis}")
        check(int(m_cpf) >= 1, f"rcpca: m_cpf must be >= 1, got {m_cpf}")
        check(float(r) > 0, f"rcpca: r must be > 0, got {r}")
        check(eta is None or float(eta) >= 0, f"rcpca: eta must be >= 0, got {eta}")
        check(int(max_iter) >= 1, f"rcpca: max_iter must be >= 1, got {max_iter}")
        check(projector_norm in ("fro", "2"), f"rcpca: projector_norm must be 'fro' or '2', got {projector_norm!r}")
        check(merge_cost in ("residual", "eq4"), f"rcpca: merge_cost must be 'residual' or 'eq4', got {merge_cost!r}")
        self.projector_norm, self.refit_before_merge = projector_norm, bool(refit_before_merge)
        self.merge_cost = merge_cost
        self.n_basis, self.m_cpf, self.r, self.eta = int(n_basis), int(m_cpf), float(r), eta
        self.q = self.n_basis + (self.n_basis if extra is None else int(extra))
        self.max_iter, self.tol, self.seed, self.cache_bytes = int(max_iter), float(tol), int(seed), int(cache_bytes)
        self.threads = threads

    # ------------------------------------------------------------------ validation / layout
    def _setup(self, stream: Any, segments: np.ndarray | None, groups: np.ndarray | None) -> None:
        check(hasattr(stream, "shape") and hasattr(stream, "__getitem__"),
              "rcpca: stream must be an array (zarr / numpy) with .shape and slicing")
        shape = tuple(int(s) for s in stream.shape)
        check(len(shape) >= 3, f"rcpca: stream must be (P, V, C, C) or (P, V, D), got shape {shape}")
        self.n_poses, self.n_verts = shape[0], shape[1]
        self.dim = int(np.prod(shape[2:]))
        self.matrix_shape = shape[2:]
        check(self.n_poses >= 1 and self.n_verts >= 1 and self.dim >= 1, f"rcpca: empty stream of shape {shape}")
        seg = np.zeros(self.n_verts, dtype=np.int64) if segments is None else np.asarray(segments)
        check(seg.shape == (self.n_verts,), f"rcpca: segments must be ({self.n_verts},), got {seg.shape}")
        check(bool(np.issubdtype(seg.dtype, np.integer)) and int(seg.min()) >= 0,
              "rcpca: segments must be non-negative integers")
        n_r = int(seg.max()) + 1
        grp = np.tile(np.arange(self.n_poses), (n_r, 1)) if groups is None else np.asarray(groups)
        check(grp.shape == (n_r, self.n_poses),
              f"rcpca: groups must be (n_segments={n_r}, P={self.n_poses}), got {grp.shape}")
        check(bool(np.issubdtype(grp.dtype, np.integer)) and int(grp.min()) >= 0,
              "rcpca: groups must be non-negative integers")
        self.segments_ = seg.astype(np.int64)
        self.groups_ = grp.astype(np.int64)
        self.n_groups = self.groups_.max(axis=1) + 1

    def _block(self, frames: _Frames, verts: np.ndarray, j: int) -> _Block:
        """Samples of the units ``(v, groups[seg v, j])`` of ``verts``, ordered by segment then vertex."""
        seg = self.segments_[verts]
        order = np.argsort(seg, kind="stable")
        verts, seg = verts[order], seg[order]
        ks, starts = np.unique(seg, return_index=True)
        bounds = np.append(starts, verts.size)
        poses = [np.flatnonzero(self.groups_[k] == self.groups_[k, j]) for k in ks]
        counts = np.concatenate([np.full(bounds[i + 1] - bounds[i], poses[i].size) for i in range(ks.size)])
        ptr = np.concatenate([[0], np.cumsum(counts)])
        x = np.empty((int(ptr[-1]), self.dim))
        need: dict[int, list[int]] = {}
        for i, ps in enumerate(poses):
            for t, p in enumerate(ps):
                need.setdefault(int(p), []).append(i * 1_000_000 + t)
        for p in sorted(need):
            f = frames(p)
            for code in need[p]:
                i, t = divmod(code, 1_000_000)
                lo, hi = bounds[i], bounds[i + 1]
                x[ptr[lo] + t: ptr[hi]: poses[i].size] = f[verts[lo:hi]]
        return _Block(x, ptr, verts)

    # ------------------------------------------------------------------ CPCA pieces
    def _errors(self, blk: _Block, models: list[_Eig | None]) -> np.ndarray:
        """``(U, K)`` summed squared error of each unit's samples in each model (inf for None)."""
        nb, k = self.n_basis, len(models)
        live = [i for i, m in enumerate(models) if m is not None]
        out = np.full((blk.verts.size, k), np.inf)
        if not live:
            return out
        mean = np.stack([models[i].mean for i in live])  # type: ignore[union-attr]
        bases = np.stack([_basis(models[i], nb) for i in live])  # type: ignore[arg-type]
        mb = np.einsum("kd,knd->kn", mean, bases)
        x2 = np.einsum("sd,sd->s", blk.x, blk.x)
        m2 = np.einsum("kd,kd->k", mean, mean)
        per = np.empty((blk.x.shape[0], len(live)))
        step = max(1, (1 << 19) // max(1, len(live) * nb))
        for s0 in range(0, blk.x.shape[0], step):
            xs = blk.x[s0:s0 + step]
            proj = (xs @ bases.reshape(-1, self.dim).T).reshape(xs.shape[0], len(live), nb) - mb[None]
            per[s0:s0 + step] = x2[s0:s0 + step, None] - 2.0 * xs @ mean.T + m2[None] - np.einsum("skn,skn->sk",
                                                                                                  proj, proj)
        out[:, live] = np.add.reduceat(np.maximum(per, 0.0), blk.ptr[:-1], axis=0)
        return out

    def _fit_models(self, blk: _Block, labels: np.ndarray, ids: range, prev: dict | None = None) -> list[_Eig | None]:
        """Models of the clusters ``ids`` from the units labelled with them; ``prev`` caches unchanged memberships."""
        sample_label = labels[blk.unit_of_sample]
        out: list[_Eig | None] = []
        for c in ids:
            members = np.flatnonzero(labels == c)
            key = (c, members.size, hash(members.tobytes()))
            if prev is not None and key in prev:
                out.append(prev[key])
                continue
            m = _eig_from(blk.x[sample_label == c], self.q) if members.size else None
            if prev is not None:
                prev[key] = m
            out.append(m)
        return out

    def _init_labels(self, blk: _Block, k: int, salt: int) -> np.ndarray:
        """k-means++ seeds (scikit-learn) among the unit means, each unit to its nearest seed: the start of a step."""
        from sklearn.cluster import kmeans_plusplus

        counts = np.diff(blk.ptr)
        means = np.add.reduceat(blk.x, blk.ptr[:-1], axis=0) / counts[:, None]
        k = min(k, blk.verts.size)
        if k <= 1:
            return np.zeros(blk.verts.size, dtype=np.int64)
        centers, _ = kmeans_plusplus(means, n_clusters=k, random_state=self.seed + salt)
        d2 = (means ** 2).sum(1)[:, None] - 2.0 * means @ centers.T + (centers ** 2).sum(1)[None]
        return np.argmin(d2, axis=1).astype(np.int64)

    def _cpca(self, blk: _Block, fixed: list[_Eig | None], k_new: int, salt: int) -> tuple[np.ndarray, list]:
        """Revised CPCA of the units of ``blk``: labels ``< len(fixed)`` pick a frozen existing model,
        ``>= len(fixed)`` one of ``k_new`` new models (fitted here). ``fixed = []`` is the original CPCA."""
        nf = len(fixed)
        labels = self._init_labels(blk, k_new, salt) + nf
        cache: dict = {}
        for _ in range(self.max_iter):
            new = self._fit_models(blk, labels, range(nf, nf + k_new), cache)
            err = self._errors(blk, list(fixed) + new)
            nxt = np.argmin(err, axis=1)
            changed = int((nxt != labels).sum())
            labels = nxt
            if changed <= self.tol * labels.size:
                break
        return labels, self._fit_models(blk, labels, range(nf, nf + k_new), cache)

    # ------------------------------------------------------------------ fit
    def fit(self, stream: Any, segments: np.ndarray | None = None, groups: np.ndarray | None = None) -> RevisedCPCA:
        """Cluster and compress ``stream (P, V, C, C)``; ``segments (V,)``, ``groups (n_r, P)`` as documented.

        BLAS / OpenMP pools are limited to ``threads`` (threadpoolctl) meanwhile: the matrices are small
        (``D x D``, ``S x D``) and oversubscribed BLAS threads are far slower than one.
        """
        from threadpoolctl import threadpool_limits

        with threadpool_limits(limits=self.threads):
            return self._fit(stream, segments, groups)

    def _fit(self, stream: Any, segments: np.ndarray | None, groups: np.ndarray | None) -> RevisedCPCA:
        t0 = time.perf_counter()
        self._setup(stream, segments, groups)
        v_all = np.arange(self.n_verts)
        frames = _Frames(stream, self.n_verts, self.dim, self.cache_bytes // max(1, self.n_verts * self.dim * 8))
        unit = np.full((self.n_verts, int(self.n_groups.max())), -1, dtype=np.int64)
        models: list[_Eig | None] = []
        n_inc = n_rec = 0
        sumsq, nsamp = 0.0, 0
        for j in range(self.n_poses):
            g_v = self.groups_[self.segments_, j]
            cl = unit[v_all, g_v]
            assigned = cl >= 0
            if assigned.all():
                continue
            rho = float(assigned.mean())
            e_j = np.unique(cl[assigned])
            if 1.0 - rho <= self.r * (self.m_cpf - e_j.size) / self.m_cpf:  # 4.1 incremental clustering
                n_inc += 1
                blk = self._block(frames, v_all[~assigned], j)
                sumsq += float(np.einsum("sd,sd->", blk.x, blk.x))
                nsamp += blk.x.shape[0]
                fixed = [models[e] for e in e_j]
                labels, new = self._cpca(blk, fixed, self.m_cpf - e_j.size, j)
                ids = np.empty(len(fixed) + len(new), dtype=np.int64)
                ids[: len(fixed)] = e_j
                uos = blk.unit_of_sample
                for i in range(len(fixed)):  # existing clusters accept new members: merge their statistics
                    sel = labels[uos] == i
                    if sel.any():
                        models[e_j[i]] = _eig_combine(models[e_j[i]], _eig_from(blk.x[sel], self.q), self.q, 1.0)
                for i, m in enumerate(new):
                    ids[len(fixed) + i] = len(models)
                    models.append(m)
            else:  # 4.2 reclustering: remove pose j's assigned units, then m_cpf new clusters by CPCA
                n_rec += 1
                blk = self._block(frames, v_all, j)
                new_mask = ~assigned[blk.verts]
                uos = blk.unit_of_sample
                sumsq += float(np.einsum("sd,sd->", blk.x[new_mask[uos]], blk.x[new_mask[uos]]))
                nsamp += int(new_mask[uos].sum())
                old = cl[blk.verts]
                for e in e_j:
                    sel = old[uos] == e
                    models[e] = _eig_combine(models[e], _eig_from(blk.x[sel], self.q), self.q, -1.0)  # type: ignore
                    if models[e] is not None and models[e].n < 1.0:  # type: ignore[union-attr]
                        models[e] = None
                labels, new = self._cpca(blk, [], self.m_cpf, j)
                ids = np.arange(len(models), len(models) + len(new))
                models.extend(new)
            unit[blk.verts, g_v[blk.verts]] = ids[labels]
        self._eta = float(self.eta) if self.eta is not None else 1.0 / math.sqrt(max(sumsq / max(nsamp, 1), 1e-30))
        created = len(models)
        if self.refit_before_merge:  # exact models of the pre-merge clusters (the downdates of 4.2 drift)
            models = self._refit(frames, len(models), unit)
        n_merge = self._merge(models, unit)
        # compact the surviving clusters to 0 .. K-1
        live = np.array([i for i, m in enumerate(models) if m is not None], dtype=np.int64)
        remap = np.full(len(models) + 1, -1, dtype=np.int64)
        remap[live] = np.arange(live.size)
        self.unit_cluster_ = np.where(unit >= 0, remap[unit], -1).astype(np.int32)
        final: list[_Eig] = self._refit(frames, int(live.size))  # type: ignore[assignment]
        self.means_ = np.stack([m.mean for m in final]).astype(np.float32)
        self.bases_ = np.stack([_basis(m, self.n_basis) for m in final]).astype(np.float32)
        self.sse_bound_ = float(sum(_residual(m, self.n_basis) for m in final))
        self._final_pass(frames)
        self.stats_ = {"incremental_steps": n_inc, "recluster_steps": n_rec, "clusters_created": created,
                       "merges": n_merge, "clusters": int(live.size), "frame_reads": frames.reads,
                       "max_clusters_per_pose": int(self.clusters_per_pose().max()),
                       "fit_seconds": time.perf_counter() - t0}
        return self

    def _pose_clusters(self, unit: np.ndarray, j: int) -> np.ndarray:
        return np.unique(unit[np.arange(self.n_verts), self.groups_[self.segments_, j]])

    def _geometry(self, m: _Eig) -> tuple:
        """What the merge cost needs of a model: eq. 4 ``(U (nb, D), residue M = m - U^T U m (D,), full rank)``;
        ``merge_cost="residual"``: ``(vecs (q, D), vals (q,), mean (D,), n, sum of the top nb eigenvalues)``,
        zero-padded to ``q`` eigenpairs."""
        if self.merge_cost == "residual":
            vecs, vals = np.zeros((self.q, m.mean.shape[0])), np.zeros(self.q)
            k = min(self.q, m.vecs.shape[0])
            vecs[:k], vals[:k] = m.vecs[:k], m.vals[:k]
            return vecs, vals, m.mean, m.n, float(vals[: self.n_basis].sum())
        u = _basis(m, self.n_basis)
        full = min(self.n_basis, m.vecs.shape[0]) == self.n_basis and bool((m.vals[: self.n_basis] > 0).all())
        return u, m.mean - u.T @ (u @ m.mean), full

    def _residual_increase(self, ga: tuple, gb: list[tuple]) -> np.ndarray:
        """Merge cost ``merge_cost="residual"``: the increase of the truncated residual energy when ``a`` and each
        ``b`` are merged, ``E(a + b) - E(a) - E(b)`` with ``E = trace - sum of the top n_basis eigenvalues``.

        The merged scatter is ``S = V_a^T L_a V_a + V_b^T L_b V_b + c d d^T`` (``d = m_a - m_b``,
        ``c = n_a n_b / (n_a + n_b)``) = ``B W B^T`` with ``B = [V_a^T, V_b^T, d]``, ``W = diag(L_a, L_b, c)``;
        its non-zero eigenvalues are those of the small ``W^1/2 (B^T B) W^1/2`` (batched ``eigvalsh``), and the
        traces cancel: cost = ``top(a) + top(b) + c |d|^2 - top(a + b)``. Exact for exact models (the models keep
        ``q = n_basis + extra`` eigenpairs).
        """
        va, la, ma, na, ta = ga
        vb = np.stack([g[0] for g in gb])
        lb = np.stack([g[1] for g in gb])
        mb = np.stack([g[2] for g in gb])
        nbv = np.array([g[3] for g in gb])
        tb = np.array([g[4] for g in gb])
        d = ma[None] - mb
        c = na * nbv / (na + nbv)
        k, q = vb.shape[0], va.shape[0]
        m = 2 * q + 1
        gram = np.empty((k, m, m))
        gram[:, :q, :q] = va @ va.T
        gram[:, :q, q:2 * q] = np.einsum("nd,kmd->knm", va, vb)
        gram[:, q:2 * q, :q] = gram[:, :q, q:2 * q].transpose(0, 2, 1)
        gram[:, q:2 * q, q:2 * q] = np.einsum("knd,kmd->knm", vb, vb)
        gram[:, :q, -1] = d @ va.T
        gram[:, q:2 * q, -1] = np.einsum("knd,kd->kn", vb, d)
        gram[:, -1, :2 * q] = gram[:, :2 * q, -1]
        dd = np.einsum("kd,kd->k", d, d)
        gram[:, -1, -1] = dd
        w = np.sqrt(np.maximum(np.concatenate([np.broadcast_to(la, (k, q)), lb, c[:, None]], axis=1), 0.0))
        lam = np.linalg.eigvalsh(gram * w[:, :, None] * w[:, None, :])
        top = lam[:, -self.n_basis:].sum(axis=1)
        return np.maximum(ta + tb + c * dd - top, 0.0)

    def _distances(self, ga: tuple, gb: list[tuple]) -> np.ndarray:
        """Eq. 4 from cluster ``a`` to each ``b``: ``||P_a - P_b|| + eta ||M_a - M_b||`` (from :meth:`_geometry`).

        ``projector_norm="2"`` (default): the spectral norm of the paper's text, ``sqrt(1 - s_min^2)`` with
        ``s_min`` the smallest singular value of ``U_a U_b^T`` (the sine of the
        largest principal angle, Golub & Van Loan); bases of lower rank use the spectral norm of the difference;
        ``"fro"``: ``||P_a - P_b||_F^2 = r_a + r_b - 2 ||U_a U_b^T||_F^2`` (orthonormal rows, ``r`` = rank).
        """
        ua, ra, full_a = ga
        ub = np.stack([g[0] for g in gb])
        rb = np.stack([g[1] for g in gb])
        cross = np.einsum("nd,kmd->knm", ua, ub)
        if self.projector_norm == "fro":
            rank_a = float(np.einsum("nd,nd->", ua, ua))
            rank_b = np.einsum("knd,knd->k", ub, ub)
            dp = np.sqrt(np.maximum(rank_a + rank_b - 2.0 * np.einsum("knm,knm->k", cross, cross), 0.0))
            return dp + self._eta * np.linalg.norm(ra[None] - rb, axis=1)
        sv = np.linalg.svd(cross, compute_uv=False)
        dp = np.sqrt(np.clip(1.0 - sv[:, -1] ** 2, 0.0, 1.0))
        for i, g in enumerate(gb):
            if not (full_a and g[2]):
                qm, _ = np.linalg.qr(np.concatenate([ua, ub[i]]).T)
                pa, pb = qm.T @ ua.T, qm.T @ ub[i].T
                dp[i] = float(np.abs(np.linalg.eigvalsh(pa @ pa.T - pb @ pb.T)).max())
        return dp + self._eta * np.linalg.norm(ra[None] - rb, axis=1)

    def _merge(self, models: list[_Eig | None], unit: np.ndarray) -> int:
        """4.3: merge minimal-distance pairs shared by an over-budget pose until every pose is in budget."""
        pose_sets = [set(self._pose_clusters(unit, j).tolist()) for j in range(self.n_poses)]
        cl_poses: dict[int, set[int]] = {}
        for j, s in enumerate(pose_sets):
            for c in s:
                cl_poses.setdefault(c, set()).add(j)
        version = [0] * len(models)
        geom = {c: self._geometry(models[c]) for s in pose_sets if len(s) > self.m_cpf for c in s}  # type: ignore
        heap: list[tuple[float, int, int, int, int]] = []
        seen: set[tuple[int, int, int, int]] = set()

        def push_pairs(cands: set[int], among: list[int]) -> None:
            for a in cands:
                if models[a] is None:
                    continue
                todo = []
                for b in among:
                    if a == b or models[b] is None:
                        continue
                    x, y = (a, b) if a < b else (b, a)
                    key = (x, y, version[x], version[y])
                    if key not in seen:
                        seen.add(key)
                        todo.append(b)
                if todo:
                    cost = self._residual_increase if self.merge_cost == "residual" else self._distances
                    dist = cost(geom[a], [geom[b] for b in todo])
                    for b, dd in zip(todo, dist, strict=True):
                        x, y = (a, b) if a < b else (b, a)
                        heapq.heappush(heap, (float(dd), x, y, version[x], version[y]))

        for s in pose_sets:
            if len(s) > self.m_cpf:
                push_pairs(s, sorted(s))
        merges = 0
        while heap and any(len(s) > self.m_cpf for s in pose_sets):
            _, a, b, va, vb = heapq.heappop(heap)
            if models[a] is None or models[b] is None or version[a] != va or version[b] != vb:
                continue
            shared = cl_poses[a] & cl_poses[b]
            if not any(len(pose_sets[p]) > self.m_cpf for p in shared):
                continue
            models[a] = _eig_combine(models[a], models[b], self.q, 1.0)  # type: ignore[arg-type]
            models[b] = None
            version[a] += 1
            geom[a] = self._geometry(models[a])  # type: ignore[arg-type]
            unit[unit == b] = a
            for p in cl_poses.pop(b):
                pose_sets[p].discard(b)
                pose_sets[p].add(a)
                cl_poses[a].add(p)
            merges += 1
            over = [p for p in cl_poses[a] if len(pose_sets[p]) > self.m_cpf]
            if over:
                push_pairs({a}, sorted(set().union(*(pose_sets[p] for p in over))))
        return merges

    def _refit(self, frames: _Frames, k: int, table: np.ndarray | None = None) -> list[_Eig | None]:
        """Stream once more: every final cluster's model from its final members, per pose, merged [HMM00].

        Only merges (no downdates), so the models are exact up to the truncation to ``q`` eigenpairs and
        ``sse_bound_`` is a true bound; it repairs the drift of the approximate downdates of 4.2.
        """
        out: list[_Eig | None] = [None] * k
        tab = self.unit_cluster_ if table is None else table
        v_all = np.arange(self.n_verts)
        for j in range(self.n_poses):
            x = frames(j)
            ids = tab[v_all, self.groups_[self.segments_, j]]
            for c in np.unique(ids[ids >= 0]):
                e = _eig_from(x[ids == c], self.q)
                out[c] = e if out[c] is None else _eig_combine(out[c], e, self.q, 1.0)  # type: ignore[arg-type]
        if table is None:
            check(all(m is not None for m in out), "rcpca: internal error: a cluster has no member after merging")
        return out

    def _final_pass(self, frames: _Frames) -> None:
        """Second stream: coefficients ``(P, V, n_basis)`` and the exact squared error."""
        self.coefficients_ = np.zeros((self.n_poses, self.n_verts, self.n_basis), dtype=np.float32)
        sse, total = 0.0, 0.0
        means, bases = self.means_.astype(np.float64), self.bases_.astype(np.float64)
        for j in range(self.n_poses):
            x = frames(j)
            ids = self.cluster_ids(j)
            total += float(np.einsum("vd,vd->", x, x))
            for c in np.unique(ids):
                idx = np.flatnonzero(ids == c)
                xc = x[idx] - means[c]
                coef = xc @ bases[c].T
                self.coefficients_[j, idx] = coef
                res = xc - coef @ bases[c]
                sse += float(np.einsum("vd,vd->", res, res))
        self.sse_, self.total_sumsq_ = sse, total

    # ------------------------------------------------------------------ results
    def cluster_ids(self, pose: int) -> np.ndarray:
        """``(V,)`` PCA cluster of every vertex at sampled pose ``pose``."""
        check(0 <= int(pose) < self.n_poses, f"rcpca: pose {pose} out of range 0..{self.n_poses - 1}")
        return self.unit_cluster_[np.arange(self.n_verts), self.groups_[self.segments_, int(pose)]].astype(np.int64)

    def clusters_per_pose(self) -> np.ndarray:
        """``(P,)`` number of distinct PCA clusters each sampled pose uses (<= ``m_cpf`` after merging)."""
        return np.array([np.unique(self.cluster_ids(j)).size for j in range(self.n_poses)])

    def reconstruct(self, poses: Any = None, quantized: bool = False) -> np.ndarray:
        """Transfer matrices ``(len(poses), V, *matrix_shape)`` float32 from means, bases and coefficients."""
        ps = np.arange(self.n_poses) if poses is None else np.atleast_1d(np.asarray(poses))
        coef = self.quantized_coefficients() if quantized else self.coefficients_
        out = np.empty((ps.size, self.n_verts, self.dim), dtype=np.float32)
        for i, j in enumerate(ps):
            ids = self.cluster_ids(int(j))
            out[i] = self.means_[ids] + np.einsum("vn,vnd->vd", coef[int(j)], self.bases_[ids])
        return out.reshape(ps.size, self.n_verts, *self.matrix_shape)

    def _coef_groups(self) -> np.ndarray:
        return np.stack([self.cluster_ids(j) for j in range(self.n_poses)]).reshape(-1)

    def quantize(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """16-bit coefficients ``(codes (P, V, n_basis) uint16, scale (K, n_basis), offset (K, n_basis))``,
        one scale/offset per cluster and basis vector."""
        codes, scale, offset = quantize16(self.coefficients_.reshape(-1, self.n_basis), self._coef_groups())
        return codes.reshape(self.coefficients_.shape), scale, offset

    def quantized_coefficients(self) -> np.ndarray:
        """The float32 coefficients the 16-bit codes decode to, ``(P, V, n_basis)``."""
        codes, scale, offset = self.quantize()
        return dequantize16(codes.reshape(-1, self.n_basis), scale, offset,
                            self._coef_groups()).reshape(self.coefficients_.shape)

    def nbytes(self) -> dict[str, float]:
        """Raw float32 bytes, stored bytes (uint16 coefficients + float32 means/bases + int32 tables), ratio."""
        k = self.means_.shape[0]
        raw = 4 * self.n_poses * self.n_verts * self.dim
        coef = quantized_nbytes(self.n_poses * self.n_verts, self.n_basis, k)
        basis = 4 * k * (self.n_basis + 1) * self.dim
        tables = 4 * (self.unit_cluster_.size + self.groups_.size + self.segments_.size)
        stored = coef + basis + tables
        return {"raw": raw, "coefficients": coef, "bases": basis, "tables": tables, "stored": stored,
                "ratio": raw / stored}

    def state(self) -> dict[str, np.ndarray]:
        """Arrays to store (e.g. in ``s001.npz``): means, bases, unit table, groups, segments, 16-bit coefficients."""
        codes, scale, offset = self.quantize()
        return {"means": self.means_, "bases": self.bases_, "unit_cluster": self.unit_cluster_,
                "groups": self.groups_, "segments": self.segments_, "coef_codes": codes,
                "coef_scale": scale, "coef_offset": offset}

    @classmethod
    def from_state(cls, state: Any) -> RevisedCPCA:
        """A fitted model back from :meth:`state` (e.g. an ``np.load``-ed npz): coefficients are the decoded
        16-bit codes; ``reconstruct``, ``cluster_ids``, ``nbytes`` work; ``fit`` statistics are absent."""
        for key in ("means", "bases", "unit_cluster", "groups", "segments", "coef_codes", "coef_scale", "coef_offset"):
            check(key in state, f"rcpca state: missing array {key!r}")
        bases = np.asarray(state["bases"], dtype=np.float32)
        m = cls(n_basis=bases.shape[1])
        m.means_, m.bases_ = np.asarray(state["means"], dtype=np.float32), bases
        m.unit_cluster_ = np.asarray(state["unit_cluster"], dtype=np.int32)
        m.groups_ = np.asarray(state["groups"], dtype=np.int64)
        m.segments_ = np.asarray(state["segments"], dtype=np.int64)
        codes = np.asarray(state["coef_codes"])
        check(codes.ndim == 3 and codes.shape[2] == m.n_basis, f"rcpca state: coef_codes shape {codes.shape}")
        m.n_poses, m.n_verts, m.dim = codes.shape[0], codes.shape[1], bases.shape[2]
        c = int(round(math.sqrt(m.dim)))
        m.matrix_shape = (c, c) if c * c == m.dim else (m.dim,)
        m.n_groups = m.groups_.max(axis=1) + 1
        m.coefficients_ = dequantize16(codes.reshape(-1, m.n_basis), state["coef_scale"], state["coef_offset"],
                                       m._coef_groups()).reshape(codes.shape)
        return m

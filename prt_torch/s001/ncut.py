"""Normalized cut (Shi & Malik 2000) and seed 001's mesh segment clustering (section 3, eq. 1-3).

Seed 001 arranges the transfer matrices of all sampled poses as a matrix whose rows are vertices and
whose columns are poses (its Fig. 2a). A *consistent segmentation* (here: the skinning clusters, one
integer label per vertex) splits the rows into segments ``k``. For every segment ``k`` the paper
builds a COMPLETE graph whose nodes are the ``P`` posed copies of that segment (one node per sampled
pose), with eq. 3's weight

    w(i, j) = exp(- sum_l ||T_l^i - T_l^j||_F^2 / (2 sigma_t^2) - sum_b ||R_b^i - R_b^j||_F^2 / (2 sigma_p^2))

(``T_l^i``: transfer matrix of vertex ``l`` of the segment at pose ``i``; ``R_b^i``: local rigid
transform of bone ``b`` at pose ``i``), and recursively bisects it with the normalized cut (eq. 1),
solving eq. 2, ``(D - W) y = lambda D y``, for the eigenvector of the second smallest eigenvalue and
splitting at its MEDIAN so both halves have equal size, until groups of ``leaf_size`` (4) poses.
The result, per segment, is a partition of the poses into groups (the paper's ``Omega_{k,g}``).

``sigma_t^2 = 1.0 x var_t`` and ``sigma_p^2 = 2.0 x var_p`` (the paper's settings). ``var_t`` is "the
variance of the transfer matrices" of the segment over the poses: ``mean_i sum_l ||T_l^i - mean_i T_l||^2``,
which equals half the mean over all ordered pairs ``(i, j)`` of the summed squared distance in the exponent,
so both terms of the exponent are O(1) on average (dimensionally consistent); ``var_p`` likewise for the bone
transforms. ``t_scale`` / ``p_scale`` expose the factors.

Eigen-solvers are scipy's: ``scipy.linalg.eigh(D - W, D)`` (the generalized problem itself) for graphs of
at most :data:`DENSE_MAX` nodes, else ``scipy.sparse.linalg.eigsh`` on ``D^-1/2 W D^-1/2`` (largest
eigenvalues ``1 - lambda``; ``y = D^-1/2 z``). A disconnected graph (or isolated nodes) gets a uniform
``eps`` link between all pairs (``eps`` = 1e-6 x the mean edge weight), which makes eq. 2 well posed and
keeps the bisection from splitting a connected component while whole components can be moved.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import scipy.linalg
import scipy.sparse as sp
import scipy.sparse.csgraph
import scipy.sparse.linalg

from prt_torch.errors import check
from prt_torch.shapes import check_shape

DENSE_MAX = 2048  # graphs up to this many nodes use the dense generalized solver (scipy.linalg.eigh)
_EPS_LINK = 1e-6


def _as_graph(w: Any, name: str = "W") -> sp.csr_matrix:
    """Validate a symmetric non-negative weight matrix and return it as float64 CSR with no diagonal."""
    check(w is not None, f"{name}: got None, expected an (N, N) weight matrix")
    m = sp.csr_matrix(w, dtype=np.float64) if sp.issparse(w) else None
    if m is None:
        a = np.asarray(w, dtype=np.float64)
        check(a.ndim == 2 and a.shape[0] == a.shape[1], f"{name}: expected a square (N, N) matrix, got shape {a.shape}")
        m = sp.csr_matrix(a)
    check(m.shape[0] == m.shape[1], f"{name}: expected a square (N, N) matrix, got shape {m.shape}")
    check(m.shape[0] >= 2, f"{name}: empty graph: need at least 2 nodes, got {m.shape[0]}")
    check(bool(np.isfinite(m.data).all()), f"{name}: contains NaN or Inf weights")
    check(bool((m.data >= 0).all()), f"{name}: weights must be non-negative")
    m = m.tolil()
    m.setdiag(0.0)
    m = m.tocsr()
    m.eliminate_zeros()
    check(m.nnz > 0, f"{name}: empty graph: no edge has a positive weight")
    asym = abs(m - m.T)
    check(asym.nnz == 0 or float(asym.max()) <= 1e-8 * float(m.max()), f"{name}: weight matrix is not symmetric")
    return m


def ncut_value(w: Any, mask: np.ndarray) -> float:
    """Eq. 1, ``cut(A,B)/asso(A,U) + cut(A,B)/asso(B,U)`` for the split ``A = mask``, ``B = ~mask``."""
    m = sp.csr_matrix(w, dtype=np.float64)
    a = np.asarray(mask, dtype=bool)
    d = np.asarray(m.sum(axis=1)).ravel()
    cut = float(m[a][:, ~a].sum())
    da, db = float(d[a].sum()), float(d[~a].sum())
    return (cut / da if da > 0 else np.inf) + (cut / db if db > 0 else np.inf)


def fiedler_vector(w: Any) -> np.ndarray:
    """Eq. 2's eigenvector ``y (N,)`` of the second smallest generalized eigenvalue of ``(D - W) y = lambda D y``."""
    m = _as_graph(w)
    n = m.shape[0]
    n_comp, _ = scipy.sparse.csgraph.connected_components(m, directed=False)
    eps = _EPS_LINK * float(m.data.mean()) if n_comp > 1 else 0.0
    if n <= DENSE_MAX:
        a = m.toarray()
        if eps:
            a = a + eps * (1.0 - np.eye(n))
        d = a.sum(axis=1)
        _, vec = scipy.linalg.eigh(np.diag(d) - a, np.diag(d), subset_by_index=[0, 1])
        y = vec[:, 1]
    else:
        d = np.asarray(m.sum(axis=1)).ravel() + eps * (n - 1)
        s = 1.0 / np.sqrt(d)

        def matvec(x: np.ndarray) -> np.ndarray:
            x = np.asarray(x).reshape(n, -1)
            sx = s[:, None] * x
            out = m @ sx
            if eps:
                out = out + eps * (sx.sum(axis=0, keepdims=True) - sx)
            return (s[:, None] * out).reshape(np.shape(x) if x.shape[1] > 1 else (n,))

        op = scipy.sparse.linalg.LinearOperator((n, n), matvec=matvec, matmat=matvec, dtype=np.float64)
        v0 = np.sqrt(d) / np.linalg.norm(np.sqrt(d))  # the known top eigenvector; a deterministic start
        vals, vecs = scipy.sparse.linalg.eigsh(op, k=2, which="LA", v0=v0 + 1e-3 * np.cos(np.arange(n)))
        z = vecs[:, int(np.argsort(vals)[0])]  # second largest of D^-1/2 W D^-1/2 = second smallest lambda
        y = s * z
    return np.asarray(y, dtype=np.float64)


def ncut_bisect(w: Any) -> np.ndarray:
    """Split a graph in two equal halves at the median of eq. 2's second eigenvector (seed 001 section 3.1).

    ``w``: ``(N, N)`` symmetric non-negative weights (scipy.sparse or dense), ``N >= 2``. Returns a bool
    mask ``(N,)`` with exactly ``N // 2`` True entries (the nodes with the largest ``y``; ties broken by
    node index), oriented so node 0 is False (deterministic).
    """
    y = fiedler_vector(w)
    n = y.shape[0]
    order = np.argsort(y, kind="stable")
    mask = np.zeros(n, dtype=bool)
    mask[order[n - n // 2:]] = True
    if mask[0]:
        mask = np.zeros(n, dtype=bool)
        mask[order[: n // 2]] = True
    return mask


def recursive_ncut(w: Any, leaf_size: int = 4) -> np.ndarray:
    """Recursive median bisection until every group has at most ``leaf_size`` nodes.

    Returns integer labels ``(N,)`` in ``0 .. n_groups - 1``, numbered in depth-first order (the False
    side of each split first), deterministic. Group sizes differ by at most one at every level, so every
    leaf has between ``ceil(leaf_size / 2)`` and ``leaf_size`` nodes when ``N >= leaf_size``.
    """
    check(int(leaf_size) >= 1, f"recursive_ncut: leaf_size must be >= 1, got {leaf_size}")
    m = _as_graph(w)
    labels = np.full(m.shape[0], -1, dtype=np.int64)
    stack = [np.arange(m.shape[0])]
    next_label = 0
    while stack:
        idx = stack.pop()
        sub = m[idx][:, idx]
        if idx.size <= leaf_size:
            labels[idx] = next_label
            next_label += 1
            continue
        if sub.nnz == 0:  # no edges left inside: any balanced split has Ncut 0; keep node order
            half = np.zeros(idx.size, dtype=bool)
            half[idx.size - idx.size // 2:] = True
        else:
            half = ncut_bisect(sub)
        stack.append(idx[half])
        stack.append(idx[~half])  # popped first: False side gets the lower labels
    return labels


def sq_dists(x: np.ndarray) -> np.ndarray:
    """``(P, P)`` summed squared differences ``||x_i - x_j||^2`` of the rows of ``x (P, ...)`` (via the Gram)."""
    f = np.asarray(x, dtype=np.float64).reshape(x.shape[0], -1)
    g = f @ f.T
    n = np.diag(g)
    return np.maximum(n[:, None] + n[None, :] - 2.0 * g, 0.0)


def affinity_from_sq_dists(dt: np.ndarray, dp: np.ndarray, t_scale: float = 1.0, p_scale: float = 2.0,
                           adjacency: Any = None) -> sp.csr_matrix:
    """Eq. 3's weights from the summed squared transfer distances ``dt (P, P)`` and pose distances ``dp (P, P)``.

    ``sigma^2 = scale x var`` with ``var = mean(d) / 2`` (``mean_{i,j} ||x_i - x_j||^2 = 2 var`` over all ordered
    pairs). ``adjacency`` (optional ``(P, P)``, sparse or dense): keep only its non-zero edges (the paper uses
    the complete graph: None). Returns a CSR matrix with a zero diagonal.
    """
    dt = np.asarray(dt, dtype=np.float64)
    dp = np.asarray(dp, dtype=np.float64)
    check_shape(dt, "P P", name="affinity: dt")
    check(dp.shape == dt.shape, f"affinity: dp shape {dp.shape} != dt shape {dt.shape}")
    check(bool(np.isfinite(dt).all() and np.isfinite(dp).all()), "affinity: distances contain NaN or Inf")
    check(t_scale > 0 and p_scale > 0, f"affinity: scales must be > 0, got {t_scale}, {p_scale}")
    expo = np.zeros_like(dt)
    for d, scale in ((dt, t_scale), (dp, p_scale)):
        var = float(d.mean()) / 2.0
        if var > 0:
            expo += d / (2.0 * scale * var)
    w = np.exp(-expo)
    np.fill_diagonal(w, 0.0)
    if adjacency is not None:
        adj = sp.csr_matrix(adjacency)
        check(adj.shape == w.shape, f"affinity: adjacency shape {adj.shape} != {w.shape}")
        return sp.csr_matrix(adj.astype(bool).multiply(w))
    return sp.csr_matrix(w)


def segment_affinity(t_seg: np.ndarray, bones: np.ndarray, adjacency: Any = None, t_scale: float = 1.0,
                     p_scale: float = 2.0) -> sp.csr_matrix:
    """Eq. 3 for ONE segment group: nodes are the ``P`` poses of the segment.

    ``t_seg (P, n_l, ...)``: the transfer matrices of the segment's ``n_l`` vertices at every pose (any
    trailing shape, e.g. ``(C, C)``); ``bones (P, B, ...)``: per pose the local rigid transform of every bone
    (e.g. ``(B, 3, 4)``). Returns the ``(P, P)`` CSR weight matrix (complete graph unless ``adjacency``).
    For data larger than memory use :func:`segment_sq_dists_streamed` then :func:`affinity_from_sq_dists`.
    """
    t = np.asarray(t_seg)
    b = np.asarray(bones)
    dims = check_shape(t, "P n_l ...", name="segment_affinity: t_seg")
    check_shape(b, "P B ...", name="segment_affinity: bones", dims=dims)
    check(t.shape[0] >= 2, f"segment_affinity: need at least 2 poses, got {t.shape[0]}")
    check(bool(np.isfinite(t).all()), "segment_affinity: t_seg contains NaN or Inf")
    check(bool(np.isfinite(b).all()), "segment_affinity: bones contain NaN or Inf")
    return affinity_from_sq_dists(sq_dists(t), sq_dists(b), t_scale, p_scale, adjacency)


def segment_sq_dists_streamed(stream: Any, segments: np.ndarray, block: int = 1024) -> np.ndarray:
    """Eq. 3's transfer term for every segment, streamed: ``(n_r, P, P)`` of ``sum_l ||T_l^i - T_l^j||_F^2``.

    ``stream``: any array with ``.shape = (P, V, ...)`` and basic slicing (a zarr array of the bake's
    ``transfer_matrix``); read in vertex blocks ``stream[:, v0:v1]`` of ``block`` vertices, so memory is
    ``P x block x C^2`` floats plus the ``(n_r, P, P)`` Gram matrices. ``segments (V,)``: labels ``0 .. n_r-1``.
    """
    shape = tuple(stream.shape)
    check_shape(stream, "P V ...", name="segment distances: stream")
    p, v = shape[0], shape[1]
    seg = np.asarray(segments)
    check_shape(seg, (v,), name="segment distances: segments")
    check(bool(np.issubdtype(seg.dtype, np.integer)) and (seg.size == 0 or seg.min() >= 0),
          "segment distances: segments must be non-negative integers")
    n_r = int(seg.max()) + 1
    gram = np.zeros((n_r, p, p))
    for v0 in range(0, v, block):
        x = np.asarray(stream[:, v0:v0 + block], dtype=np.float64)
        x = x.reshape(p, x.shape[1], -1)
        check(bool(np.isfinite(x).all()), f"segment distances: stream has NaN or Inf in vertices {v0}..")
        s = seg[v0:v0 + block]
        for k in np.unique(s):
            xk = x[:, s == k].reshape(p, -1)
            gram[k] += xk @ xk.T
    n = np.diagonal(gram, axis1=1, axis2=2)
    return np.maximum(n[:, :, None] + n[:, None, :] - 2.0 * gram, 0.0)


def cluster_segments(stream: Any, segments: np.ndarray, bones: np.ndarray, leaf_size: int = 4,
                     t_scale: float = 1.0, p_scale: float = 2.0, block: int = 1024) -> np.ndarray:
    """Seed 001 section 3.2: per segment, recursive normalized cut of its posed copies.

    Returns ``groups (n_r, P)`` int: ``groups[k, j]`` = the pose group (``Omega_{k,g}``) of pose ``j`` in
    segment ``k``, labels ``0 .. n_groups_k - 1``. ``stream (P, V, ...)`` streamed in vertex blocks;
    ``bones (P, B, ...)`` the local bone transforms per pose; ``segments (V,)`` the skinning clusters.
    """
    b = np.asarray(bones, dtype=np.float64)
    p = int(stream.shape[0])
    check_shape(b, (p, "B", "..."), name="cluster_segments: bones")
    check(bool(np.isfinite(b).all()), "cluster_segments: bones contain NaN or Inf")
    dt = segment_sq_dists_streamed(stream, segments, block)
    dp = sq_dists(b)
    groups = np.zeros((dt.shape[0], p), dtype=np.int64)
    for k in range(dt.shape[0]):
        groups[k] = recursive_ncut(affinity_from_sq_dists(dt[k], dp, t_scale, p_scale), leaf_size)
    return groups

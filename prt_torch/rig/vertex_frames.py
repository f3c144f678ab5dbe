"""Temporally coherent local vertex frames (seed 003, section 5.2). numpy + scikit-learn only.

The mesh is split into near-rigid parts by mean-shift clustering of the skinning weights; each
part gets the first PCA direction of its rest-pose vertices, carried each frame by the rotation of
the part's dominant bone and projected into every vertex's tangent plane::

    n = posed smooth normal,  a = normalise(R_bone(f) a_rest),  t = normalise(a - (a.n) n),  b = n x t

Frame rows are ``(t, b, n)`` (docs/DESIGN.md): a world direction ``w`` has local coordinates
``F @ w``. Where ``a`` is nearly parallel to ``n`` the projection is ill-conditioned, so a second
fixed axis ``p`` perpendicular to ``a`` (carried by the same bone) is blended in smoothly:
``t ~ t_a + w t_p`` with ``w = clip(1 - |t_a| / FALLBACK_BELOW, 0, 1)``; ``w = 0`` (pure PCA
tangent) wherever ``|t_a| >= FALLBACK_BELOW``.

Two implementations of the one rule, tested against each other: :func:`vertex_frames` (the
reference: float64, ``(..., V, 3, 3)``, used by the bake) and :func:`vertex_frames_soa` (float32,
vertex-last ``(B, 9, V)`` rows with preallocated scratch, the player's per-frame fast path). Both use
:data:`FALLBACK_BELOW` and :data:`DEGENERATE_BELOW`.

This module must not import torch: the player rebuilds frames with it every frame, from the
dataset's ``cluster (V,)``, ``cluster_axis (Kc, 3)`` and ``cluster_bone (Kc,)``.
"""

from __future__ import annotations

import warnings

import numpy as np

from prt_torch.errors import PrtError
from prt_torch.shapes import check_shape

#: below this tangent-plane length of the PCA axis the fallback axis is blended in
FALLBACK_BELOW = 0.3

#: a blended tangent shorter than this is degenerate (a measure-zero coincidence): any perpendicular is used
DEGENERATE_BELOW = 1e-6

#: mean shift is fitted on at most this many vertices (a seeded subsample); all vertices are then labelled
FIT_SAMPLES = 1000


def cluster_vertices(
    weights: np.ndarray,
    bandwidth: float | None = None,
    max_clusters: int = 64,
    min_size: int = 8,
    seed: int = 0,
) -> np.ndarray:
    """Mean-shift clustering of dense skinning weights into near-rigid parts.

    Args:
        weights: ``(V, J)`` dense skinning weights (rows sum to 1).
        bandwidth: flat-kernel radius in weight space; ``None``: ``sklearn.cluster.estimate_bandwidth``
            (quantile 0.1) clamped to ``[0.2, 0.5]`` (pure single-bone vertices are ``sqrt 2`` apart).
        max_clusters: merge the smallest clusters until at most this many remain.
        min_size: clusters with fewer vertices are merged into the nearest cluster (centre distance).
        seed: seed of the bandwidth estimate's subsample.

    Returns:
        ``(V,)`` int32 labels ``0..Kc-1``, numbered in order of first appearance (deterministic).
    """
    from sklearn.cluster import MeanShift, estimate_bandwidth, get_bin_seeds
    from threadpoolctl import threadpool_limits

    w = np.asarray(weights, dtype=np.float64)
    check_shape(w, "V J", name="skinning weights")
    if w.shape[0] == 0:
        raise PrtError(f"skinning weights must have shape (V, J) with V > 0, got {w.shape}")
    if not np.isfinite(w).all():
        raise PrtError("skinning weights contain NaN or Inf")
    if max_clusters < 1 or min_size < 1:
        raise PrtError(f"max_clusters and min_size must be >= 1, got {max_clusters} and {min_size}")
    V = w.shape[0]
    if bandwidth is None:
        with threadpool_limits(limits=1):
            bandwidth = float(estimate_bandwidth(w, quantile=0.1, n_samples=min(V, 2000), random_state=seed))
        bandwidth = float(np.clip(bandwidth, 0.2, 0.5))
    if not bandwidth > 0:
        raise PrtError(f"mean-shift bandwidth must be > 0, got {bandwidth}")
    if V == 1:
        return np.zeros(1, dtype=np.int32)
    # fit on a fixed subsample (mean shift is quadratic-ish), then give every vertex its nearest mode
    fit = w if V <= FIT_SAMPLES else w[np.sort(np.random.default_rng(seed).choice(V, FIT_SAMPLES, replace=False))]
    # single-threaded BLAS: the many tiny neighbour queries are 10x slower with threads on a busy machine
    with threadpool_limits(limits=1), warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)  # "binning failed, using data points as seeds": fine
        seeds = get_bin_seeds(fit, bandwidth, min_bin_freq=3)  # bins of >= 3 vertices seed the modes
        if len(seeds) == 0:
            seeds = get_bin_seeds(fit, bandwidth, min_bin_freq=1)
        ms = MeanShift(bandwidth=bandwidth, seeds=seeds, cluster_all=True, n_jobs=1)
        ms.fit(fit)
        labels = ms.predict(w)
    labels = _merge_small(w, labels, max_clusters, min_size)
    # renumber in order of first appearance
    _, first = np.unique(labels, return_index=True)
    order = np.argsort(first, kind="stable")
    remap = np.empty(labels.max() + 1, dtype=np.int32)
    remap[np.unique(labels)[order]] = np.arange(len(order), dtype=np.int32)
    return remap[labels]


def _merge_small(w: np.ndarray, labels: np.ndarray, max_clusters: int, min_size: int) -> np.ndarray:
    """Merge the smallest cluster into the nearest other centre until all are big enough and few enough."""
    labels = labels.copy()
    ids = list(np.unique(labels))
    sizes = {k: int(np.sum(labels == k)) for k in ids}
    sums = {k: w[labels == k].sum(axis=0) for k in ids}
    while len(ids) > 1:
        smallest = min(ids, key=lambda k: (sizes[k], k))
        if sizes[smallest] >= min_size and len(ids) <= max_clusters:
            break
        c = sums[smallest] / sizes[smallest]
        others = [k for k in ids if k != smallest]
        dist = [float(np.linalg.norm(sums[k] / sizes[k] - c)) for k in others]
        target = others[int(np.argmin(dist))]
        labels[labels == smallest] = target
        sizes[target] += sizes.pop(smallest)
        sums[target] = sums[target] + sums.pop(smallest)
        ids.remove(smallest)
    return labels


def cluster_bones(weights: np.ndarray, labels: np.ndarray) -> np.ndarray:
    """``(Kc,)`` int32 dominant bone of each cluster: the joint with the largest summed weight."""
    w = np.asarray(weights, dtype=np.float64)
    labels = _check_labels(labels, w.shape[0])
    k = int(labels.max()) + 1
    summed = np.zeros((k, w.shape[1]))
    np.add.at(summed, labels, w)
    return np.argmax(summed, axis=1).astype(np.int32)


def cluster_axes(rest_vertices: np.ndarray, labels: np.ndarray) -> np.ndarray:
    """``(Kc, 3)`` float32 unit first PCA direction of each cluster's rest vertices.

    The sign is fixed so that the largest-magnitude component is positive; a cluster with fewer
    than two distinct vertices gets the world ``x`` axis.
    """
    x = np.asarray(rest_vertices, dtype=np.float64)
    check_shape(x, "V 3", name="rest vertices")
    labels = _check_labels(labels, x.shape[0])
    k = int(labels.max()) + 1
    count = np.bincount(labels, minlength=k).astype(np.float64)
    mean = np.zeros((k, 3))
    np.add.at(mean, labels, x)
    mean /= count[:, None]
    d = x - mean[labels]
    cov = np.zeros((k, 3, 3))
    np.add.at(cov, labels, d[:, :, None] * d[:, None, :])
    evals, evecs = np.linalg.eigh(cov)  # ascending
    axis = evecs[:, :, 2]
    degenerate = evals[:, 2] <= 1e-12 * max(1.0, float(np.abs(x).max()) ** 2)
    axis[degenerate] = (1.0, 0.0, 0.0)
    big = np.argmax(np.abs(axis), axis=1)
    axis *= np.sign(axis[np.arange(k), big])[:, None]
    return axis.astype(np.float32)


def fallback_axes(axes: np.ndarray) -> np.ndarray:
    """``(Kc, 3)`` a fixed unit vector perpendicular to each axis (cross with the least aligned world axis)."""
    a = np.asarray(axes, dtype=np.float64)
    e = np.eye(3)[np.argmin(np.abs(a), axis=1)]
    p = np.cross(a, e)
    return p / np.linalg.norm(p, axis=1, keepdims=True)


def vertex_frames(
    normals: np.ndarray,
    skin: np.ndarray,
    labels: np.ndarray,
    axes: np.ndarray,
    bones: np.ndarray,
) -> np.ndarray:
    """Vertex frames of posed meshes.

    Args:
        normals: ``(..., V, 3)`` posed smooth normals (normalised here).
        skin: ``(..., J, 3, 3)`` bone rotations (or ``(..., J, 4, 4)`` skin matrices, whose
            upper-left block is used), same leading shape as ``normals``.
        labels: ``(V,)`` cluster of each vertex.
        axes: ``(Kc, 3)`` rest-pose cluster axes (:func:`cluster_axes`).
        bones: ``(Kc,)`` dominant bone of each cluster (:func:`cluster_bones`).

    Returns:
        ``(..., V, 3, 3)`` float32, rows ``(t, b, n)``, orthonormal and right-handed.
    """
    n = np.asarray(normals, dtype=np.float64)
    rot = np.asarray(skin, dtype=np.float64)
    if rot.shape[-2:] == (4, 4):
        rot = rot[..., :3, :3]
    check_shape(n, "... V 3", name="normals")
    check_shape(rot, (*n.shape[:-2], "J", 3, 3), name="skin rotations")
    if not (np.isfinite(n).all() and np.isfinite(rot).all()):
        raise PrtError("normals or skin matrices contain NaN or Inf")
    labels = _check_labels(labels, n.shape[-2])
    axes = np.asarray(axes, dtype=np.float64)
    bones = np.asarray(bones)
    if axes.ndim != 2 or axes.shape[1] != 3 or bones.shape != (axes.shape[0],) or labels.max() >= axes.shape[0]:
        raise PrtError(f"cluster axes {axes.shape} / bones {bones.shape} do not match {labels.max() + 1} clusters")
    if bones.min() < 0 or bones.max() >= rot.shape[-3]:
        raise PrtError(f"cluster bones must index joints 0..{rot.shape[-3] - 1}")
    n = n / np.maximum(np.linalg.norm(n, axis=-1, keepdims=True), 1e-12)
    r = rot[..., bones, :, :]  # (..., Kc, 3, 3)
    a = _normalise(np.einsum("...kij,kj->...ki", r, axes))[..., labels, :]  # (..., V, 3)
    p = _normalise(np.einsum("...kij,kj->...ki", r, fallback_axes(axes)))[..., labels, :]
    ta = a - np.sum(a * n, axis=-1, keepdims=True) * n
    tp = p - np.sum(p * n, axis=-1, keepdims=True) * n
    la = np.linalg.norm(ta, axis=-1, keepdims=True)
    w = np.clip(1.0 - la / FALLBACK_BELOW, 0.0, 1.0)
    t = ta + w * tp
    lt = np.linalg.norm(t, axis=-1, keepdims=True)
    bad = lt[..., 0] < DEGENERATE_BELOW
    if bad.any():  # a measure-zero coincidence: any perpendicular will do
        alt = np.cross(n[bad], np.eye(3)[np.argmin(np.abs(n[bad]), axis=-1)])
        t[bad] = alt
        lt[bad] = np.linalg.norm(alt, axis=-1, keepdims=True)
    t = t / lt
    b = np.cross(n, t)
    return np.stack([t, b, n], axis=-2).astype(np.float32)


def vertex_frames_soa(nrm: np.ndarray, rot: np.ndarray, labels: np.ndarray, axes2: np.ndarray,
                      s1: np.ndarray, s3: np.ndarray) -> np.ndarray:
    """The rule of :func:`vertex_frames` in float32, vertex-last (the player's fast path).

    Args:
        nrm: ``(B, 3, V)`` float32 unit posed normals.
        rot: ``(B, Kc, 3, 3)`` rotations of each cluster's dominant bone (float64).
        labels: ``(V,)`` intp cluster of each vertex.
        axes2: ``(2, Kc, 3)`` float64 rest-pose cluster axes and their :func:`fallback_axes`.
        s1, s3: ``(B, V)`` and ``(B, 3, V)`` float32 scratch buffers (overwritten).

    Returns:
        ``(B, 9, V)`` float32, entry ``3i + j`` = ``F[i, j]``, rows ``(t, b, n)``.
    """
    mul, add = np.multiply, np.add
    b, _, v = nrm.shape
    ap = np.einsum("bkij,mkj->bmik", rot, axes2)  # (B, 2, 3, Kc): [axis; fallback] carried by the bones
    ap /= np.maximum(np.sqrt((ap * ap).sum(axis=2, keepdims=True)), 1e-12)
    ap = np.take(ap.astype(np.float32), labels, axis=3)  # (B, 2, 3, V)
    a, p = ap[:, 0], ap[:, 1]
    for x in (a, p):  # tangents of both axes: x - (x . n) n, in place
        dot3(x, nrm, s1, s3)
        mul(nrm, s1[:, None], out=s3)
        x -= s3
    la = dot3(a, a, s1, s3)
    np.sqrt(la, out=la)
    # fallback weight w = clip(1 - |ta| / FALLBACK_BELOW, 0, 1): t = ta + w tp
    mul(la, -1.0 / np.float32(FALLBACK_BELOW), out=la)
    la += 1.0
    np.clip(la, 0.0, 1.0, out=la)
    mul(p, la[:, None], out=p)
    t = add(a, p, out=a)
    lt = np.sqrt(dot3(t, t, s1, s3))
    if (lt < DEGENERATE_BELOW).any():  # measure-zero coincidence: any perpendicular, as the reference does
        t = t.copy()
        bi, vi = np.nonzero(lt < DEGENERATE_BELOW)
        n = nrm[bi, :, vi]  # (m, 3)
        t[bi, :, vi] = np.cross(n, np.eye(3, dtype=np.float32)[np.argmin(np.abs(n), axis=-1)])
        lt = np.sqrt(dot3(t, t, s1, s3))
    frames = np.empty((b, 9, v), np.float32)
    np.divide(t, lt[:, None], out=frames[:, 0:3])
    t = frames[:, 0:3]
    # b = n x t
    mul(nrm[:, 1], t[:, 2], out=frames[:, 3])
    frames[:, 3] -= mul(nrm[:, 2], t[:, 1], out=s1)
    mul(nrm[:, 2], t[:, 0], out=frames[:, 4])
    frames[:, 4] -= mul(nrm[:, 0], t[:, 2], out=s1)
    mul(nrm[:, 0], t[:, 1], out=frames[:, 5])
    frames[:, 5] -= mul(nrm[:, 1], t[:, 0], out=s1)
    frames[:, 6:9] = nrm
    return frames


def dot3(a: np.ndarray, b: np.ndarray, out: np.ndarray, tmp: np.ndarray) -> np.ndarray:
    """``out (B, V) = sum_i a[:, i] * b[:, i]`` for ``(B, 3, V)`` arrays (``tmp (B, 3, V)`` scratch)."""
    np.multiply(a, b, out=tmp)
    np.add(tmp[:, 0], tmp[:, 1], out=out)
    return np.add(out, tmp[:, 2], out=out)


def _normalise(x: np.ndarray) -> np.ndarray:
    return x / np.maximum(np.linalg.norm(x, axis=-1, keepdims=True), 1e-12)


def _check_labels(labels: np.ndarray, n_vertices: int) -> np.ndarray:
    labels = np.asarray(labels)
    check_shape(labels, (n_vertices,), name="cluster labels")
    if not np.issubdtype(labels.dtype, np.integer):
        raise PrtError(f"cluster labels must be ({n_vertices},) integers, got {labels.dtype} {labels.shape}")
    if n_vertices and labels.min() < 0:
        raise PrtError("cluster labels must be >= 0")
    return labels.astype(np.intp)

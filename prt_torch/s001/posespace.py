"""Pose-space interpolation of sampled poses (seed 001 sec. 5): nearest sampled poses by k-d tree, NRBF weights
with a bone-weighted pose distance (eq. 6), and interpolated PCA coefficients (eq. 7).

Pure numpy + scipy (no torch in this module).

Pose features are the dataset's ``pose (A,)`` 6D features (:mod:`prt_torch.rig.features`: 6 numbers per non-root
joint, ``A = 6 J'``). The bone-weighted pose distance of segment ``k`` (eq. 6: "larger weight to the bone which the
mesh segment belongs to than other bones") is

    d_k(p, q)^2 = sum_j w_kj || f_j(p) - f_j(q) ||^2,     w_kj = max(other, s_kj / max_j s_kj)

with ``s_kj`` the mean skinning weight of the segment's vertices on joint ``j`` (:func:`segment_bone_weights`);
scaling the features by ``sqrt(w_kj)`` turns it into a Euclidean distance, so one :class:`scipy.spatial.cKDTree`
per segment answers the nearest sampled pose. The global baseline (``posespace``) uses ``w = 1`` for every joint.

NRBF weights (normalised Gaussian radial basis functions, Nelles 2000) over ``L`` candidate poses at distances
``d_l``: ``alpha_l = phi_l / sum_m phi_m``, ``phi_l = exp(-d_l^2 / (2 sigma^2))`` with the width tied to the
nearest candidate, ``sigma = scale * d_min``: non-negative, summing to 1, and exactly one-hot on a sampled pose
(``d_min = 0``; continuous there, since ``phi_l / phi_min -> 0`` as ``d_min -> 0``).

Two schemes over the same compressed data (Table 3):

* ``s001`` (:meth:`PoseSpace.segment_neighbours`): per segment ``k``, the nearest sampled pose ``j*`` under ``d_k``
  picks the normalized-cut pose group ``g = groups[k, j*]``; the neighbours are that group's poses, weighted by
  NRBF of ``d_k``.
* ``posespace`` (:meth:`PoseSpace.global_neighbours`): the ``L`` nearest sampled poses under the unweighted
  distance, the same for every segment, NRBF-weighted.

Eq. 7: ``lambda_v = sum_l alpha_l c[j_l, v]`` (:func:`interpolate_coefficients`).
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field

import numpy as np
from scipy.spatial import cKDTree

from prt_torch.errors import DamagedArtifact, check
from prt_torch.io import atomic_write_bytes, read_npz_with_meta
from prt_torch.shapes import check_shape

FEATURES_PER_JOINT = 6


def segment_bone_weights(segment: np.ndarray, joints: np.ndarray, weights: np.ndarray, n_segments: int,
                         feature_joints: np.ndarray, other: float = 0.25) -> np.ndarray:
    """Eq. 6 per-segment joint weights ``(K, J')`` float64 in ``[other, 1]``.

    Args:
        segment: ``(V,)`` int segment of each vertex (``0..n_segments-1``).
        joints, weights: ``(V, I)`` skinning influences (joint index into the full skeleton) and their weights.
        feature_joints: ``(J',)`` the skeleton joint of each 6D feature block (the non-root joints in order).
        other: the weight floor of joints that do not skin the segment.
    """
    segment = np.asarray(segment)
    check(segment.ndim == 1 and joints.shape == weights.shape and joints.shape[0] == segment.shape[0],
          f"segment (V,) and skinning (V, I) disagree: {segment.shape}, {joints.shape}, {weights.shape}")
    check(0.0 <= other <= 1.0, f"other bone weight must be in [0, 1], got {other}")
    n_joints = int(max(int(joints.max(initial=0)), int(np.max(feature_joints, initial=0)))) + 1
    s = np.zeros((n_segments, n_joints))
    np.add.at(s, (np.repeat(segment, joints.shape[1]), joints.reshape(-1)), weights.reshape(-1))
    s = s[:, np.asarray(feature_joints)]
    top = s.max(axis=1, keepdims=True)
    s = np.divide(s, top, out=np.zeros_like(s), where=top > 0)
    return np.maximum(s, other)


def feature_scale(joint_weights: np.ndarray) -> np.ndarray:
    """``(..., A)`` multipliers ``sqrt(w_j)`` repeated over each joint's 6 features (Euclidean form of eq. 6)."""
    return np.repeat(np.sqrt(np.asarray(joint_weights, dtype=np.float64)), FEATURES_PER_JOINT, axis=-1)


def nrbf_weights(d: np.ndarray, scale: float = 1.0, valid: np.ndarray | None = None) -> np.ndarray:
    """NRBF weights ``(..., L)`` float64 from distances ``d (..., L)`` (module doc); ``valid``: mask of real
    candidates (padding gets weight 0). Non-negative, each row sums to 1, one-hot where ``d_min = 0``."""
    d = np.asarray(d, dtype=np.float64)
    check(scale > 0, f"NRBF scale must be > 0, got {scale}")
    check(bool(np.all(np.isfinite(d))) and bool(np.all(d >= 0)), "NRBF distances must be finite and >= 0")
    valid = np.ones(d.shape, bool) if valid is None else np.asarray(valid, bool)
    check(bool(np.all(valid.any(axis=-1))), "NRBF: every query needs at least one candidate pose")
    dm = np.where(valid, d, np.inf)
    dmin = dm.min(axis=-1, keepdims=True)
    sigma2 = 2.0 * (scale * dmin) ** 2
    with np.errstate(divide="ignore", invalid="ignore"):
        expo = np.where(sigma2 > 0, -(dm**2 - dmin**2) / np.where(sigma2 > 0, sigma2, 1.0), 0.0)
    phi = np.where(valid, np.exp(expo), 0.0)
    exact = (dmin == 0) & valid
    phi = np.where(dmin == 0, (dm == 0) & exact, phi)  # on a sampled pose: that pose (ties share)
    return phi / phi.sum(axis=-1, keepdims=True)


def segment_rotations(frames: np.ndarray, ref: np.ndarray, segment: np.ndarray, n_segments: int) -> np.ndarray:
    """Per-segment rotations ``R_k (..., K, 3, 3)`` float64 taking the reference pose to the posed one.

    ``frames (..., V, 3, 3)`` posed vertex frames and ``ref (V, 3, 3)`` the reference pose's (rows ``t, b, n`` in
    world coordinates; a vertex carried rigidly by ``R`` has ``F = F_ref R^T``): ``R_k`` is the orthogonal
    Procrustes solution ``argmin sum_{v in k} ||F_v^T - R F_ref,v^T||_F`` (polar factor of ``sum_v F_v^T F_ref,v``).
    """
    frames = np.asarray(frames, dtype=np.float64)
    ref = np.asarray(ref, dtype=np.float64)
    v = ref.shape[0]
    check_shape(ref, "V 3 3", name="reference frames")
    check_shape(frames, ("*", v, 3, 3), name="frames")
    m = np.einsum("...vji,vjk->...vik", frames, ref).reshape(*frames.shape[:-3], v, 9)
    onehot = np.zeros((n_segments, v))
    onehot[np.asarray(segment), np.arange(v)] = 1.0
    acc = (onehot @ m).reshape(*frames.shape[:-3], n_segments, 3, 3)
    u, _, vt = np.linalg.svd(acc)
    det = np.sign(np.linalg.det(u @ vt))
    u[..., :, -1] *= det[..., None]
    return u @ vt


@dataclass
class PoseSpace:
    """The sampled poses and the interpolation metric.

    Attributes:
        poses: ``(P, A)`` float64 pose features of the sampled (training) poses.
        joint_weights: ``(K, J')`` eq. 6 weights per segment.
        groups: ``(K, P)`` int normalized-cut pose group of each sampled pose, per segment.
        scale: NRBF width relative to the nearest candidate distance.
    """

    poses: np.ndarray
    joint_weights: np.ndarray
    groups: np.ndarray
    scale: float = 1.0
    _trees: list[cKDTree] = field(default_factory=list, repr=False)
    _global: cKDTree | None = field(default=None, repr=False)

    def __post_init__(self) -> None:
        self.poses = np.asarray(self.poses, dtype=np.float64)
        self.joint_weights = np.asarray(self.joint_weights, dtype=np.float64)
        self.groups = np.asarray(self.groups, dtype=np.int64)
        p, a = self.poses.shape
        k = self.joint_weights.shape[0]
        check(a == FEATURES_PER_JOINT * self.joint_weights.shape[1],
              f"pose features ({a}) do not match {self.joint_weights.shape[1]} joints x 6")
        check_shape(self.groups, (k, p), name="groups")
        check(bool(np.all(np.isfinite(self.poses))), "sampled poses contain NaN or inf")
        self._scales = feature_scale(self.joint_weights)  # (K, A)
        self._trees = [cKDTree(self.poses * self._scales[i]) for i in range(k)]
        self._global = cKDTree(self.poses)
        # members[k][g] -> pose indices, padded to the largest group
        sizes = [np.bincount(self.groups[i]) for i in range(k)]
        self.max_group = int(max(int(s.max()) for s in sizes))
        n_groups = int(self.groups.max()) + 1
        self._members = np.full((k, n_groups, self.max_group), -1, np.int64)
        for i in range(k):
            order = np.argsort(self.groups[i], kind="stable")
            g_sorted = self.groups[i][order]
            start = np.searchsorted(g_sorted, np.arange(n_groups))
            slot = np.arange(p) - start[g_sorted]
            self._members[i, g_sorted, slot] = order

    @property
    def n_segments(self) -> int:
        return int(self.joint_weights.shape[0])

    def _check_pose(self, pose: np.ndarray) -> np.ndarray:
        pose = np.asarray(pose, dtype=np.float64).reshape(-1)
        check(pose.shape[0] == self.poses.shape[1],
              f"pose has {pose.shape[0]} features, the sampled poses {self.poses.shape[1]}")
        check(bool(np.all(np.isfinite(pose))), "pose contains NaN or inf")
        return pose

    def segment_neighbours(self, pose: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``s001``: per segment, the pose group of its nearest sampled pose under ``d_k`` and NRBF weights.

        Returns ``idx (K, L)`` int sampled-pose indices (padding repeats a member) and ``alpha (K, L)`` float64.
        """
        pose = self._check_pose(pose)
        q = pose[None] * self._scales  # (K, A)
        nearest = np.array([t.query(q[i])[1] for i, t in enumerate(self._trees)], np.int64)
        ks = np.arange(self.n_segments)
        members = self._members[ks, self.groups[ks, nearest]]  # (K, L)
        valid = members >= 0
        idx = np.where(valid, members, members[:, :1])
        diff = (self.poses[idx] - pose) * self._scales[:, None]  # (K, L, A)
        d = np.sqrt(np.einsum("kla,kla->kl", diff, diff))
        return idx, nrbf_weights(d, self.scale, valid)

    def global_neighbours(self, pose: np.ndarray, n: int | None = None) -> tuple[np.ndarray, np.ndarray]:
        """``posespace``: the ``n`` (default: the largest group size) nearest sampled poses under the unweighted
        distance, one set for the whole body; ``idx (n,)``, ``alpha (n,)``."""
        pose = self._check_pose(pose)
        n = min(n or self.max_group, self.poses.shape[0])
        d, idx = self._global.query(pose, k=n)
        d, idx = np.atleast_1d(d), np.atleast_1d(idx)
        return idx.astype(np.int64), nrbf_weights(d, self.scale)


def interpolate_coefficients(coeffs: np.ndarray, idx: np.ndarray, alpha: np.ndarray) -> np.ndarray:
    """Eq. 7: ``lambda (V, nb) = sum_l alpha[v, l] coeffs[idx[v, l], v]`` for ``coeffs (P, V, nb)`` (float or
    dequantised), per-vertex neighbours ``idx (V, L)`` and weights ``alpha (V, L)``."""
    v = coeffs.shape[1]
    dims = check_shape(idx, (v, "L"), name="idx")
    check_shape(alpha, (v, "L"), name="alpha", dims=dims)
    c = coeffs[idx, np.arange(v)[:, None]]  # (V, L, nb)
    return np.einsum("vl,vlb->vb", alpha, c)


#: arrays of ``s001.npz`` (every one is run-time data, counted by :meth:`CompressedTransfer.stored_bytes`)
ARRAYS = ("poses", "joint_weights", "groups", "segment", "vertex_cluster", "mean", "basis", "coeff_q", "coeff_offset",
          "coeff_scale", "ref_frames")


@dataclass
class CompressedTransfer:
    """The compressed per-pose transfer matrices of seed 001 (``runs/<name>/s001.npz``).

    ``P`` sampled poses, ``V`` vertices, ``K`` segments, ``M`` PCA clusters of ``nb`` basis matrices, ``D = C*C``.

    Segment-relative matrices: the store's ``T`` (rows local-frame radiance, columns GLOBAL light) carries the
    rotation of its body part, which no interpolation of poses can follow; the compressed matrices are
    ``T_k = T D(R_k)`` (``D`` = :func:`prt_torch.sh.rotation.sh_rotation`, ``R_k`` = :func:`segment_rotations` of
    the vertex's segment from ``ref_frames``), so that ``T L = T_k (D(R_k)^T L)``: columns in the segment's
    reference-pose frame, nearly pose-invariant for a rigid unshadowed part (measured on the tiny store: the
    relative spread over the sampled poses drops from 0.64 to 0.20). At run time the lighting is rotated once per
    segment and frame. Flattened row-major.

    Attributes:
        poses: ``(P, A)`` float32 pose features of the sampled poses; joint_weights ``(K, J')`` eq. 6 weights;
        groups: ``(K, P)`` int16 normalized-cut group of each pose per segment; segment ``(V,)`` int32;
        vertex_cluster: ``(G, V)`` int32 PCA cluster of vertex ``v`` in pose group ``g`` of its segment;
        mean: ``(M, D)`` float32; basis ``(M, nb, D)`` float32 orthonormal rows;
        coeff_q: ``(P, V, nb)`` uint16 16-bit coefficients (:func:`prt_torch.s001.quantize.quantize16` per PCA
        cluster), ``c = coeff_offset[m] + q * coeff_scale[m]`` with ``m`` the vertex's cluster in that pose;
        coeff_offset / coeff_scale ``(M, nb)`` float32;
        ref_frames: ``(V, 3, 3)`` float32 the reference pose's vertex frames;
        meta: order, scale, raw bytes, fit settings and timings.
    """

    poses: np.ndarray
    joint_weights: np.ndarray
    groups: np.ndarray
    segment: np.ndarray
    vertex_cluster: np.ndarray
    mean: np.ndarray
    basis: np.ndarray
    coeff_q: np.ndarray
    coeff_offset: np.ndarray
    coeff_scale: np.ndarray
    ref_frames: np.ndarray
    meta: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        p, v, nb = self.coeff_q.shape
        m, nb2, d = self.basis.shape
        k = self.joint_weights.shape[0]
        check(nb == nb2 and self.mean.shape == (m, d) and self.coeff_offset.shape == (m, nb)
              and self.coeff_scale.shape == (m, nb), "s001 data: basis, mean and coefficient ranges disagree")
        check(self.poses.shape[0] == p and self.groups.shape == (k, p) and self.segment.shape == (v,)
              and self.vertex_cluster.shape[1] == v, "s001 data: poses, groups, segments and vertices disagree")
        check(int(np.sqrt(d)) ** 2 == d, f"s001 data: basis length {d} is not C*C")
        check(int(self.segment.max(initial=0)) < k and int(self.vertex_cluster.max(initial=0)) < m,
              "s001 data: segment or cluster index out of range")

    @property
    def n_coeffs(self) -> int:
        return int(round(np.sqrt(self.basis.shape[2])))

    @property
    def n_vertices(self) -> int:
        return int(self.coeff_q.shape[1])

    def posespace(self) -> PoseSpace:
        return PoseSpace(self.poses, self.joint_weights, self.groups, float(self.meta.get("scale", 1.0)))

    def _vertex_axis(self, idx: np.ndarray) -> np.ndarray:
        check_shape(idx, (self.n_vertices, "*"), name="pose indices")
        return np.arange(self.n_vertices).reshape((-1,) + (1,) * (idx.ndim - 1))

    def pose_cluster(self, idx: np.ndarray) -> np.ndarray:
        """PCA cluster ``(V, ...)`` of each vertex in the sampled poses ``idx (V, ...)``."""
        v = self._vertex_axis(idx)
        return self.vertex_cluster[self.groups[self.segment[v], idx], v]

    def coefficients(self, idx: np.ndarray) -> np.ndarray:
        """Dequantised coefficients ``(V, ..., nb)`` float32 of each vertex in the sampled poses ``idx (V, ...)``."""
        v = self._vertex_axis(idx)
        cl = self.pose_cluster(idx)
        q = self.coeff_q[idx, v].astype(np.float32)
        return self.coeff_offset[cl] + q * self.coeff_scale[cl]

    def reconstruct(self, pose_index: int) -> np.ndarray:
        """The stored (compressed, segment-relative) matrices ``T_k (V, C, C)`` float32 of sampled pose
        ``pose_index``."""
        idx = np.full(self.n_vertices, int(pose_index))
        cl = self.pose_cluster(idx)
        t = self.mean[cl] + np.einsum("vb,vbd->vd", self.coefficients(idx), self.basis[cl])
        c = self.n_coeffs
        return t.reshape(-1, c, c)

    def stored_bytes(self) -> int:
        """Bytes of the run-time arrays (what the player loads)."""
        return int(sum(getattr(self, n).nbytes for n in ARRAYS))

    def save(self, path: str | os.PathLike[str]) -> None:
        """Write atomically as ``.npz`` with a JSON ``meta`` entry."""
        import io as _io
        import json

        buf = _io.BytesIO()
        np.savez(buf, meta=np.array(json.dumps(self.meta, sort_keys=True)),
                 **{n: getattr(self, n) for n in ARRAYS})
        atomic_write_bytes(path, buf.getvalue())

    @classmethod
    def load(cls, path: str | os.PathLike[str]) -> CompressedTransfer:
        """Read ``s001.npz`` (a missing or malformed file: one-line :class:`PrtError`)."""
        data, meta = read_npz_with_meta(path, "s001")
        missing = [n for n in ARRAYS if n not in data]
        if missing:
            raise DamagedArtifact(f"{path}: s001 file lacks {', '.join(missing)} (re-run `prt train`)")
        return cls(**{n: data[n] for n in ARRAYS}, meta=meta)

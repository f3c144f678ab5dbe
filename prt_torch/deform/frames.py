"""Vertex frames without bones: the rest tangent carried by the one-ring deformation gradient. numpy + scipy.

The ONE rule for deformable subjects (cloth), used by the bake, compare and the player. Frame rows are
``(t, b, n)`` (docs/DESIGN.md: a world direction ``w`` has local coordinates ``F @ w``).

**Rest frame.** Clusters (e.g. :func:`prt_torch.deform.clusters.spatial_clusters`) get their first PCA axis
(:func:`prt_torch.rig.vertex_frames.cluster_axes`); the rest frame ``(t0, b0, n0)`` of each vertex is exactly
the skinned rule :func:`prt_torch.rig.vertex_frames.vertex_frames` at rest (identity bone): ``n0`` = rest smooth
normal (:func:`prt_torch.rig.mesh.vertex_normals`), ``t0`` = the cluster axis projected into the rest tangent
plane (with that rule's :func:`~prt_torch.rig.vertex_frames.fallback_axes` blend where the axis is near ``n0``),
``b0 = n0 x t0``.

**Deformation gradient.** Vertex ``i`` with one-ring neighbours ``j`` (edge-adjacent), rest edges
``e_j = X_j - X_i`` and their rest tangent-plane coordinates ``u_j = (e_j . t0, e_j . b0)``. The least-squares
deformation gradient ``A_i (3 x 2)`` of the tangent plane, ``min sum_j |A u_j - (x_j - x_i)|^2``, is
``A = sum_j (x_j - x_i) u_j^T M^-1`` with ``M = sum_j u_j u_j^T``. Its images of ``t0`` and ``b0`` are linear
in the posed positions with FIXED coefficients::

    a_t = A (1, 0) = sum_j c_ij (x_j - x_i),   c_ij = u_j^T M^-1 (1, 0)
    a_b = A (0, 1) = sum_j d_ij (x_j - x_i),   d_ij = u_j^T M^-1 (0, 1)

so both are one sparse product ``[a_t; a_b] = S @ x`` with the fixed CSR matrix ``S (2V, V)`` (row ``i``:
``c_ij`` at column ``j``, ``-sum_j c_ij`` on the diagonal; rows ``V + i`` the same with ``d``).

**Posed frame.** With ``n`` the posed smooth normal (:func:`prt_torch.rig.mesh.vertex_normals`, the same rule
as skinned meshes; :func:`prt_torch.rig.mesh.vertex_normals_soa` on the fast path)::

    t = normalise( (a_t - (a_t . n) n) + a_b x n ),   b = n x t

i.e. the carried tangent projected into the posed tangent plane plus the carried bitangent turned back by 90
degrees about ``n``. For a planar one-ring mapped by ``A = R U`` (``R`` a rotation onto the posed tangent plane,
``U`` symmetric positive 2x2: the polar decomposition) this is ``A t0 + cof(A) t0 = R (U + det(U) U^-1) t0 =
tr(U) R t0`` (Cayley-Hamilton), i.e. exactly the polar rotation of the deformation gradient applied to ``t0``:
stretch does not turn the tangent, and a degenerate ``a_t`` (parallel to ``n`` or zero) is covered by
``a_b x n``.

**Exact for rigid motion.** Let ``x_k = R X_k + T`` (``R`` a rotation). Then ``x_j - x_i = R e_j``; writing
``e_j = u_j[0] t0 + u_j[1] b0 + (e_j . n0) n0`` (``t0, b0, n0`` orthonormal) gives
``sum_j c_ij e_j = (sum_j c_ij u_j)[0] t0 + (sum_j c_ij u_j)[1] b0 + beta n0 = t0 + beta n0`` because
``sum_j u_j u_j^T M^-1 (1, 0) = (1, 0)``; so ``a_t = R t0 + beta R n0`` and likewise ``a_b = R b0 + gamma R n0``.
Area-weighted normals are translation invariant and rotate with the mesh: ``n = R n0``. Hence
``a_t - (a_t . n) n = R t0`` and ``a_b x n = R (b0 x n0) + 0 = R t0``; the sum is ``2 R t0``, so ``t = R t0``,
``n = R n0``, ``b = R b0``: the posed frame is the rest frame rotated by ``R``, exactly (up to rounding). At
rest (``R = I``) it reproduces the rest frame.

**Degenerate cases** (no NaN): a vertex whose rest one-ring does not span its tangent plane (isolated, or all
neighbours collinear: ``det M <= 1e-12 tr(M)^2``) gets zero rows in ``S``; where ``|t| <`` :data:`DEGENERATE_BELOW`
before normalising (no usable carried direction: a measure-zero collapse), ``t`` is ``n`` crossed with the world
axis least aligned with ``n`` (the skinned rule's last resort).

Two implementations of the rule, tested against each other: :meth:`FrameOperator.frames` (reference, float64
arithmetic) and :meth:`FrameOperator.frames_soa` (float32, vertex-last, the player's path).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp

from prt_torch.deform.mesh import edge_pairs
from prt_torch.errors import check
from prt_torch.rig.mesh import normal_scatter, vertex_normals, vertex_normals_soa
from prt_torch.rig.vertex_frames import DEGENERATE_BELOW, cluster_axes, vertex_frames
from prt_torch.shapes import check_shape

#: a one-ring whose 2x2 tangent-plane moment ``M`` has ``det M <= SINGULAR * tr(M)^2`` gets no gradient
SINGULAR = 1e-12

#: :meth:`FrameOperator.frames` works through long sequences this many frames at a time
CHUNK = 64

#: keys of :meth:`FrameOperator.arrays`
ARRAY_KEYS = ("deform_op_data", "deform_op_indices", "deform_op_indptr", "deform_faces", "deform_labels",
              "deform_rest_frames")


def _normalise(x: np.ndarray) -> np.ndarray:
    return x / np.maximum(np.linalg.norm(x, axis=-1, keepdims=True), 1e-300)


@dataclass
class FrameOperator:
    """Fixed data of the rule (module docstring) for one mesh.

    Attributes:
        operator: ``(2V, V)`` float64 CSR ``S``: ``S @ x`` = carried rest tangents (rows ``0..V-1``) and
            bitangents (rows ``V..2V-1``).
        faces: ``(T, 3)`` int64 triangles (counter-clockwise seen from the normal side).
        labels: ``(V,)`` int32 cluster of each vertex.
        rest_frames: ``(V, 3, 3)`` float32 rest frames, rows ``(t0, b0, n0)``.
    """

    operator: sp.csr_matrix
    faces: np.ndarray
    labels: np.ndarray
    rest_frames: np.ndarray
    _op32: sp.csr_matrix = field(init=False, repr=False)
    _scatter: sp.csr_matrix = field(init=False, repr=False)

    def __post_init__(self) -> None:
        v = self.labels.shape[0]
        check_shape(self.operator, (2 * v, v), name="frame operator")
        check_shape(self.rest_frames, (v, 3, 3), name="rest frames")
        check(self.faces.ndim == 2 and self.faces.shape[1] == 3 and int(self.faces.max()) < v
              and int(self.faces.min()) >= 0, f"frame operator faces must be (T, 3) indices into {v} vertices")
        self._op32 = self.operator.astype(np.float32)
        self._scatter = normal_scatter(self.faces, v)

    @property
    def n_vertices(self) -> int:
        return int(self.labels.shape[0])

    @classmethod
    def from_rest(cls, rest_vertices: np.ndarray, faces: np.ndarray, labels: np.ndarray) -> FrameOperator:
        """Build the operator from the rest mesh ``(V, 3)``, its faces ``(T, 3)`` and cluster labels ``(V,)``.

        Any triangle mesh with finite positions and in-range indices works (seams, boundaries and several
        components included); cloth should pass :func:`prt_torch.deform.mesh.check_deformable_mesh` first.
        """
        x = np.asarray(rest_vertices, dtype=np.float64)
        check_shape(x, "V 3", name="rest vertices")
        check(x.shape[0] > 0, f"rest vertices must be (V, 3), got {x.shape}")
        check(bool(np.isfinite(x).all()), "rest vertices contain NaN or inf")
        f = np.asarray(faces)
        check_shape(f, "T 3", name="faces")
        check(f.shape[0] > 0 and np.issubdtype(f.dtype, np.integer),
              f"faces must be (T, 3) integers, got {f.dtype} {f.shape}")
        f = f.astype(np.int64)
        v = x.shape[0]
        check(int(f.min()) >= 0 and int(f.max()) < v, f"face index out of range [0, {v})")
        lab = np.asarray(labels)
        check_shape(lab, (v,), name="cluster labels")
        check(np.issubdtype(lab.dtype, np.integer) and int(lab.min()) >= 0,
              f"cluster labels must be ({v},) integers >= 0, got {lab.dtype} {lab.shape}")
        lab = lab.astype(np.int32)
        n0 = vertex_normals(x, f).astype(np.float64)
        axes = cluster_axes(x, lab)
        kc = axes.shape[0]
        rest = vertex_frames(n0, np.eye(3)[None], lab, axes, np.zeros(kc, np.int32)).astype(np.float64)
        # exact float64 orthonormal basis (the stored float32 rows are rounded)
        n0 = _normalise(n0)
        t0 = _normalise(rest[:, 0] - np.sum(rest[:, 0] * n0, axis=-1, keepdims=True) * n0)
        b0 = np.cross(n0, t0)
        pairs = edge_pairs(f, v)
        src = np.concatenate([pairs[:, 0], pairs[:, 1]])
        dst = np.concatenate([pairs[:, 1], pairs[:, 0]])
        e = x[dst] - x[src]
        u0, u1 = np.sum(e * t0[src], axis=1), np.sum(e * b0[src], axis=1)
        m00 = np.bincount(src, u0 * u0, minlength=v)
        m01 = np.bincount(src, u0 * u1, minlength=v)
        m11 = np.bincount(src, u1 * u1, minlength=v)
        det = m00 * m11 - m01 * m01
        ok = det > SINGULAR * (m00 + m11) ** 2
        inv_det = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)[src]
        c = (u0 * m11[src] - u1 * m01[src]) * inv_det
        d = (u1 * m00[src] - u0 * m01[src]) * inv_det
        ar = np.arange(v)
        rows = np.concatenate([src, ar, src + v, ar + v])
        cols = np.concatenate([dst, ar, dst, ar])
        data = np.concatenate([c, -np.bincount(src, c, minlength=v), d, -np.bincount(src, d, minlength=v)])
        op = sp.coo_matrix((data, (rows, cols)), shape=(2 * v, v)).tocsr()
        op.sum_duplicates()
        op.sort_indices()
        frames0 = np.stack([t0, b0, n0], axis=1).astype(np.float32)
        return cls(operator=op, faces=f, labels=lab, rest_frames=frames0)

    # ------------------------------------------------------------------ the rule

    def frames(self, positions: np.ndarray) -> np.ndarray:
        """Reference: ``positions (B, V, 3)`` or ``(V, 3)`` -> ``(B, V, 3, 3)`` float32 rows ``(t, b, n)``.

        Float64 arithmetic (in chunks of :data:`CHUNK` frames); normals by :func:`prt_torch.rig.mesh.vertex_normals`
        (one call per frame, ~3 ms at 7.7k vertices).
        """
        x = np.asarray(positions, dtype=np.float64)
        if x.ndim == 2:
            x = x[None]
        v = self.n_vertices
        check(x.ndim == 3 and x.shape[1:] == (v, 3), f"positions must be (B, {v}, 3) or ({v}, 3), got {x.shape}")
        check(bool(np.isfinite(x).all()), "positions contain NaN or inf")
        if x.shape[0] > CHUNK:  # bound the float64 temporaries of long sequences
            return np.concatenate([self.frames(x[s:s + CHUNK]) for s in range(0, x.shape[0], CHUNK)])
        b = x.shape[0]
        n = np.stack([vertex_normals(xb, self.faces) for xb in x]).astype(np.float64)  # (B, V, 3)
        y = self.operator @ x.transpose(1, 0, 2).reshape(v, 3 * b)  # (2V, 3B)
        a_t = y[:v].reshape(v, b, 3).transpose(1, 0, 2)
        a_b = y[v:].reshape(v, b, 3).transpose(1, 0, 2)
        t = a_t - np.sum(a_t * n, axis=-1, keepdims=True) * n + np.cross(a_b, n)
        lt = np.linalg.norm(t, axis=-1, keepdims=True)
        bad = lt[..., 0] < DEGENERATE_BELOW
        if bad.any():
            nb = n[bad]
            t[bad] = np.cross(nb, np.eye(3)[np.argmin(np.abs(nb), axis=-1)])
            lt[bad] = np.linalg.norm(t[bad], axis=-1, keepdims=True)
        t = t / lt
        return np.stack([t, np.cross(n, t), n], axis=-2).astype(np.float32)

    def frames_soa(self, positions_soa: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Fast path (float32, vertex-last): ``positions (B, 3, V)`` -> ``(frames (B, 9, V), normals (B, 3, V))``.

        Entry ``3i + j`` of ``frames`` is ``F[i, j]`` (rows ``(t, b, n)``), the player's layout
        (:mod:`prt_torch.player.posing`). The same rule as :meth:`frames`, in float32 (agrees to ~1e-4 for positions
        within a few metres of the origin). No finiteness check (the hot path): NaN positions give NaN frames.
        Measured ~0.8 ms per frame at 7.7k vertices on one Xeon core (about half of it the normals).
        """
        p = np.ascontiguousarray(positions_soa, dtype=np.float32)
        v = self.n_vertices
        check_shape(p, ("B", 3, v), name="positions")
        b = p.shape[0]
        n = vertex_normals_soa(p, self.faces, self._scatter)  # (B, 3, V)
        carried = np.empty((b, 3, 2 * v), np.float32)  # [a_t | a_b] per coordinate row
        for i in range(b):  # one sparse mat-vec per row: much faster than one sparse mat-multivector product
            for c in range(3):
                carried[i, c] = self._op32 @ p[i, c]
        a_t, a_b = carried[:, :, :v], carried[:, :, v:]
        out = np.empty((b, 9, v), np.float32)
        t, bt = out[:, 0:3], out[:, 3:6]
        s = np.einsum("bcv,bcv->bv", a_t, n)
        np.multiply(n, s[:, None], out=t)
        np.subtract(a_t, t, out=t)
        _cross_add(a_b, n, t)  # t += a_b x n
        lt = np.sqrt(np.einsum("bcv,bcv->bv", t, t))
        bad = lt < DEGENERATE_BELOW
        if bad.any():
            bi, vi = np.nonzero(bad)
            nb = n[bi, :, vi]
            t[bi, :, vi] = np.cross(nb, np.eye(3, dtype=np.float32)[np.argmin(np.abs(nb), axis=-1)])
            lt = np.sqrt(np.einsum("bcv,bcv->bv", t, t))
        t /= lt[:, None]
        bt.fill(0.0)
        _cross_add(n, t, bt)  # b = n x t
        out[:, 6:9] = n
        return out, n

    # ------------------------------------------------------------------ shipping

    def arrays(self) -> dict[str, np.ndarray]:
        """Everything needed to rebuild the operator (keys :data:`ARRAY_KEYS`), for an ``.npz``."""
        op = self.operator
        return {"deform_op_data": op.data.astype(np.float64), "deform_op_indices": op.indices.astype(np.int32),
                "deform_op_indptr": op.indptr.astype(np.int64), "deform_faces": self.faces.astype(np.int32),
                "deform_labels": self.labels.astype(np.int32),
                "deform_rest_frames": self.rest_frames.astype(np.float32)}

    @classmethod
    def from_arrays(cls, d: dict[str, np.ndarray]) -> FrameOperator:
        """Inverse of :meth:`arrays` (any mapping with those keys, e.g. an opened ``.npz``)."""
        missing = [k for k in ARRAY_KEYS if k not in d]
        check(not missing, f"frame operator arrays lack {missing}")
        labels = np.asarray(d["deform_labels"]).astype(np.int32)
        v = labels.shape[0]
        indptr = np.asarray(d["deform_op_indptr"]).astype(np.int64)
        check_shape(indptr, (2 * v + 1,), name="frame operator indptr")
        op = sp.csr_matrix((np.asarray(d["deform_op_data"], dtype=np.float64),
                            np.asarray(d["deform_op_indices"]).astype(np.int32), indptr), shape=(2 * v, v))
        return cls(operator=op, faces=np.asarray(d["deform_faces"]).astype(np.int64), labels=labels,
                   rest_frames=np.asarray(d["deform_rest_frames"], dtype=np.float32))


def _cross_add(a: np.ndarray, b: np.ndarray, out: np.ndarray) -> None:
    """``out += a x b`` for ``(B, 3, V)`` float32 arrays (vertex-last)."""
    out[:, 0] += a[:, 1] * b[:, 2] - a[:, 2] * b[:, 1]
    out[:, 1] += a[:, 2] * b[:, 0] - a[:, 0] * b[:, 2]
    out[:, 2] += a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]


def _tangent_angles(frames: np.ndarray, pairs: np.ndarray) -> np.ndarray:
    t = np.asarray(frames, dtype=np.float64)[..., 0, :]
    t = _normalise(t)
    a, b = t[..., pairs[:, 0], :], t[..., pairs[:, 1], :]
    return np.degrees(np.arctan2(np.linalg.norm(np.cross(a, b), axis=-1), np.sum(a * b, axis=-1)))  # small-angle exact


def frame_coherence(frames: np.ndarray, faces: np.ndarray, labels: np.ndarray | None = None,
                    rest: np.ndarray | None = None) -> float:
    """Worst angle (degrees) between the tangents of edge-neighbouring vertices, over all frames.

    Args:
        frames: ``(F, V, 3, 3)`` (or ``(V, 3, 3)``) rows ``(t, b, n)``.
        faces: ``(T, 3)`` triangles (their edges are the neighbour pairs).
        labels: ``(V,)`` clusters; when given only pairs inside one cluster count (across a cluster boundary the
            tangents follow different PCA axes by design, already at rest).
        rest: ``(V, 3, 3)`` rest frames (e.g. :attr:`FrameOperator.rest_frames`); when given, the result is the
            worst CHANGE of a pair's angle from its rest value (on closed bodies neighbouring tangents already
            differ a lot at rest where the cluster axis meets the normal; cloth sheets start near 0).

    Returns:
        The largest angle (or change), 0 when no pair counts. A smooth sheet with coherent frames gives about its
        bending per edge (e.g. ``h / r`` radians on a cylinder of radius ``r`` with edges ``h``).
    """
    fr = np.asarray(frames)
    check(fr.ndim in (3, 4) and fr.shape[-2:] == (3, 3), f"frames must be (F, V, 3, 3), got {fr.shape}")
    v = fr.shape[-3]
    pairs = edge_pairs(faces, v)
    if labels is not None:
        lab = np.asarray(labels)
        check_shape(lab, (v,), name="labels")
        pairs = pairs[lab[pairs[:, 0]] == lab[pairs[:, 1]]]
    if pairs.size == 0:
        return 0.0
    ang = _tangent_angles(fr, pairs)
    if rest is not None:
        r = np.asarray(rest)
        check_shape(r, (v, 3, 3), name="rest frames")
        ang = np.abs(ang - _tangent_angles(r, pairs))
    return float(ang.max())


def frame_turn(frames: np.ndarray) -> float:
    """Worst angle (degrees) a vertex tangent turns between consecutive frames of ``(F, V, 3, 3)`` (temporal
    coherence, as the skinned frames are checked in tests/rig); 0 for a single frame."""
    fr = np.asarray(frames, dtype=np.float64)
    check_shape(fr, "F V 3 3", name="frames")
    if fr.shape[0] < 2:
        return 0.0
    t = _normalise(fr[..., 0, :])
    return float(np.degrees(np.arctan2(np.linalg.norm(np.cross(t[1:], t[:-1]), axis=-1),
                                       np.sum(t[1:] * t[:-1], axis=-1))).max())

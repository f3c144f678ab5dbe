"""The per-frame posing path in float32, vertex-last ("structure of arrays") for speed.

Computes for a batch of local joint transforms exactly what the library's reference functions
compute - FK (:func:`prt_torch.rig.skeleton.forward_kinematics`), LBS
(:func:`prt_torch.rig.skinning.skin`), local vertex frames (:func:`prt_torch.rig.vertex_frames.vertex_frames`),
pose features (:func:`prt_torch.rig.features.pose_features`) - but laid out as ``(B, 3, V)`` /
``(B, 9, V)`` rows so that every step is a small GEMM or an elementwise op on contiguous
V-long rows (tests check it against the reference functions). numpy only.

Outputs per batch of ``B`` poses: ``positions (B, 3, V)``, ``normals (B, 3, V)``, frames
``(B, 9, V)`` (entry ``3i + j`` is ``F[i, j]``, rows ``(t, b, n)``), ``view_dirs (B, 3, V)`` unit
vectors to the eye, ``features (B, A)``.
"""

from __future__ import annotations

import numpy as np

from prt_torch.errors import PrtError, check
from prt_torch.rig.vertex_frames import dot3, fallback_axes, vertex_frames_soa
from prt_torch.shapes import check_shape


class PoseBatch:
    """Posed characters, vertex-last float32 arrays (see module docstring).

    ``positions``, ``normals``, ``frames``, ``view_dirs`` always read in the ORIGINAL vertex order. A batch posed
    in an export order (``order``: position ``i`` holds original vertex ``order[i]``, the cluster-sorted order of
    the fused graph) keeps its arrays in that order - :meth:`in_order` hands them to the graph as they are - and
    puts them back into the original order only when a field is read (once, cached). Assigning a field stores
    it in the original order.
    """

    _FIELDS = ("positions", "normals", "frames", "view_dirs")

    def __init__(self, positions: np.ndarray, normals: np.ndarray, frames: np.ndarray, view_dirs: np.ndarray,
                 features: np.ndarray, order: np.ndarray | None = None, skin: np.ndarray | None = None) -> None:
        self._raw = {"positions": positions, "normals": normals, "frames": frames, "view_dirs": view_dirs}
        self._orig: dict[str, np.ndarray] = {}
        self.features = features  # (B, A)
        self.order = order
        self.skin = skin  # (B, J, 4, 4) float64 skinning matrices (world @ inverse bind), when posed by a Poser
        #: ``(B, V, P)`` float32 visible fraction of each peak light's disc (original vertex order), set by
        #: :meth:`prt_torch.player.player.Player.compute` (``P = 0`` without peaks)
        self.peak_visibility: np.ndarray | None = None
        #: ``(B, V, 3)`` float32 radiance of the SH path alone (the residual lighting; original order), set there too
        self.residual_radiance: np.ndarray | None = None

    def __repr__(self) -> str:
        b, _, v = self._raw["positions"].shape
        return f"PoseBatch(B={b}, V={v}, order={'original' if self.order is None else 'export'})"

    def _original(self, name: str) -> np.ndarray:
        if self.order is None:
            return self._raw[name]
        if name not in self._orig:
            raw = self._raw[name]
            out = np.empty_like(raw)
            out[..., self.order] = raw
            self._orig[name] = out
        return self._orig[name]

    def _set(self, name: str, value: np.ndarray) -> None:
        if self.order is None:
            self._raw[name] = value
        else:
            self._orig[name] = value
            self._raw[name] = np.ascontiguousarray(np.asarray(value)[..., self.order])

    positions = property(lambda self: self._original("positions"), lambda self, v: self._set("positions", v),
                         doc="``(B, 3, V)`` world positions, original vertex order")
    normals = property(lambda self: self._original("normals"), lambda self, v: self._set("normals", v),
                       doc="``(B, 3, V)`` unit world normals, original vertex order")
    frames = property(lambda self: self._original("frames"), lambda self, v: self._set("frames", v),
                      doc="``(B, 9, V)`` frames (entry ``3i + j`` is ``F[i, j]``), original vertex order")
    view_dirs = property(lambda self: self._original("view_dirs"), lambda self, v: self._set("view_dirs", v),
                         doc="``(B, 3, V)`` unit directions vertex -> eye, original vertex order")

    def in_order(self, name: str, order: np.ndarray | None) -> np.ndarray:
        """Field ``name`` with its vertex axis in ``order`` (``None``: original): free when posed in ``order``."""
        if order is self.order or (order is not None and self.order is not None and np.array_equal(order, self.order)):
            return self._raw[name]
        orig = self._original(name)
        return orig if order is None else np.ascontiguousarray(orig[..., order])

    def positions_vx3(self, index: int = 0) -> np.ndarray:
        """``(V, 3)`` positions of character ``index`` (for rendering), original vertex order."""
        return np.ascontiguousarray(self.positions[index].T)

    def frames_vx33(self) -> np.ndarray:
        """``(B, V, 3, 3)`` frames in the DESIGN.md layout, original vertex order."""
        b, _, v = self.frames.shape
        return np.ascontiguousarray(self.frames.transpose(0, 2, 1).reshape(b, v, 3, 3))


class Poser:
    """Precomputed per-character state of the posing path (weights, rest mesh, cluster axes).

    Args:
        character: a :class:`prt_torch.rig.Character`.
        cluster: ``(V,)`` cluster labels; cluster_axis: ``(Kc, 3)``; cluster_bone: ``(Kc,)`` (the
            dataset's frame data, as in :func:`prt_torch.rig.vertex_frames.vertex_frames`).
        order: pose in this vertex order (``(V,)`` permutation: position ``i`` is original vertex ``order[i]``;
            the fused graph's cluster-sorted order) - the weights and rest mesh are permuted once here, so the
            posing costs the same; ``None``: the original order.
    """

    def __init__(self, character, cluster: np.ndarray, cluster_axis: np.ndarray, cluster_bone: np.ndarray,
                 order: np.ndarray | None = None) -> None:

        self.character = character
        v = character.num_vertices
        cluster = np.asarray(cluster)
        check_shape(cluster, (v,), name="cluster labels")
        axes = np.asarray(cluster_axis, dtype=np.float64)
        bones = np.asarray(cluster_bone).astype(np.intp)
        check(axes.ndim == 2 and axes.shape[1] == 3 and bones.shape == (axes.shape[0],)
              and int(cluster.max()) < axes.shape[0], "cluster axes / bones do not match the cluster labels")
        if order is not None:
            order = np.asarray(order).astype(np.intp)
            check(order.shape == (v,) and np.array_equal(np.sort(order), np.arange(v)),
                  f"vertex order must be a permutation of {v} vertices")
        self.order = order
        sel = slice(None) if order is None else order
        self.labels = cluster.astype(np.intp)[sel]
        self.axes = axes
        self.fallback = fallback_axes(axes)
        self.bones = bones
        self.w_t = np.ascontiguousarray(character.dense_weights.T[:, sel], dtype=np.float32)  # (J, V)
        self.rest = np.ascontiguousarray(character.rest_vertices.T[:, sel], dtype=np.float32)  # (3, V)
        self.rest_n = np.ascontiguousarray(character.rest_normals.T[:, sel], dtype=np.float32)
        self.n_vertices = v
        #: ``(2, Kc, 3)`` float64 rest-pose cluster axes and their fallback axes
        self.axes2 = np.stack([self.axes, self.fallback])
        self._buffers: tuple[np.ndarray, np.ndarray] | None = None

    def checked_local(self, local: np.ndarray) -> np.ndarray:
        """``local`` as float64 ``(B, J, 4, 4)``, checked (shape, B >= 1, finite): one-line errors otherwise."""
        ch = self.character
        local = np.asarray(local, dtype=np.float64)
        check_shape(local, ("B", ch.num_joints, 4, 4), name="local joint transforms")
        if local.shape[0] < 1:
            raise PrtError(f"local joint transforms must be (B, {ch.num_joints}, 4, 4) with B >= 1, got {local.shape}")
        if not np.isfinite(local).all():
            raise PrtError("local joint transforms contain NaN or Inf")
        return local

    def features(self, local: np.ndarray) -> np.ndarray:
        """``(B, A)`` float32 pose features of ``local (B, J, 4, 4)`` alone (checked; no FK/LBS): what the
        visibility model needs, so that it can start before the rest of the posing path."""
        from prt_torch.rig.features import pose_features

        ch = self.character
        local = self.checked_local(local)
        return np.ascontiguousarray(pose_features(local, ch.bind_local, ch.parents), dtype=np.float32)

    def __call__(self, local: np.ndarray, eye: np.ndarray, features: np.ndarray | None = None) -> PoseBatch:
        """Pose ``local (B, J, 4, 4)`` joint transforms; ``eye (3,)`` camera position for the view directions.

        ``features``: the ``(B, A)`` result of :meth:`features` for the same ``local`` when already computed.
        """
        from prt_torch.rig.features import pose_features
        from prt_torch.rig.skeleton import forward_kinematics

        ch = self.character
        local = self.checked_local(local)
        b = local.shape[0]
        skin = forward_kinematics(ch.parents, local) @ ch.inverse_bind[None]  # (B, J, 4, 4) float64
        rows = skin[:, :, :3, :].reshape(b, -1, 12).transpose(0, 2, 1).astype(np.float32)  # (B, 12, J)
        blend = rows @ self.w_t  # (B, 12, V): blended 3x4 matrix entries, vertex-last
        v = self.n_vertices
        mul, add = np.multiply, np.add
        s1, s3 = self._scratch(b)  # (B, V) and (B, 3, V) float32 scratch, reused between calls
        # LBS: blend viewed as (B, 3, 4, V): pos_i = sum_j blend[i, j] X_j (X = x, y, z, 1), normals without j = 3
        bm = blend.reshape(b, 3, 4, v)
        pos = np.empty((b, 3, v), np.float32)
        nrm = np.empty((b, 3, v), np.float32)
        mul(bm[:, :, 0], self.rest[0], out=pos)
        add(pos, bm[:, :, 3], out=pos)
        mul(bm[:, :, 0], self.rest_n[0], out=nrm)
        for j in (1, 2):
            mul(bm[:, :, j], self.rest[j], out=s3)
            add(pos, s3, out=pos)
            mul(bm[:, :, j], self.rest_n[j], out=s3)
            add(nrm, s3, out=nrm)
        _normalize(nrm, s1, s3)
        frames = vertex_frames_soa(nrm, skin[:, self.bones, :3, :3], self.labels, self.axes2, s1, s3)
        view = np.subtract(np.asarray(eye, dtype=np.float32).reshape(1, 3, 1), pos)
        _normalize(view, s1, s3)
        if features is None:
            features = np.ascontiguousarray(pose_features(local, ch.bind_local, ch.parents), dtype=np.float32)
        return PoseBatch(pos, nrm, frames, view, features, order=self.order, skin=skin)

    def _scratch(self, b: int) -> tuple[np.ndarray, np.ndarray]:
        """``(B, V)`` and ``(B, 3, V)`` float32 scratch buffers, allocated once per batch size."""
        if self._buffers is None or self._buffers[0].shape[0] != b:
            self._buffers = (np.empty((b, self.n_vertices), np.float32),
                             np.empty((b, 3, self.n_vertices), np.float32))
        return self._buffers


def _normalize(x: np.ndarray, s1: np.ndarray, s3: np.ndarray) -> None:
    """Normalise the ``(B, 3, V)`` vectors ``x`` in place (lengths clamped at 1e-12)."""
    n = dot3(x, x, s1, s3)
    np.sqrt(n, out=n)
    np.maximum(n, 1e-12, out=n)
    np.divide(1.0, n, out=n)
    np.multiply(x, n[:, None], out=x)

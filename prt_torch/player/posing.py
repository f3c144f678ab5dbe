"""The per-frame posing path in float32, vertex-last ("structure of arrays") for speed.

Computes for a batch of local joint transforms exactly what the library's reference functions
compute - FK (:func:`prt_torch.rig.skeleton.forward_kinematics`), LBS
(:func:`prt_torch.rig.skinning.skin`), local vertex frames (:func:`prt_torch.bake.frames.local_frames`),
pose features (:func:`prt_torch.rig.features.pose_features`) - but laid out as ``(B, 3, V)`` /
``(B, 9, V)`` rows so that every step is a small GEMM or an elementwise op on contiguous
V-long rows (tests check it against the reference functions). numpy only.

Outputs per batch of ``B`` poses: ``positions (B, 3, V)``, ``normals (B, 3, V)``, frames
``(B, 9, V)`` (entry ``3i + j`` is ``F[i, j]``, rows ``(t, b, n)``), ``view_dirs (B, 3, V)`` unit
vectors to the eye, ``features (B, A)``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from prt_torch.errors import PrtError, check


@dataclass
class PoseBatch:
    """Posed characters, vertex-last float32 arrays (see module docstring)."""

    positions: np.ndarray  # (B, 3, V)
    normals: np.ndarray  # (B, 3, V)
    frames: np.ndarray  # (B, 9, V)
    view_dirs: np.ndarray  # (B, 3, V)
    features: np.ndarray  # (B, A)

    def positions_vx3(self, index: int = 0) -> np.ndarray:
        """``(V, 3)`` positions of character ``index`` (for rendering)."""
        return np.ascontiguousarray(self.positions[index].T)

    def frames_vx33(self) -> np.ndarray:
        """``(B, V, 3, 3)`` frames in the DESIGN.md layout."""
        b, _, v = self.frames.shape
        return np.ascontiguousarray(self.frames.transpose(0, 2, 1).reshape(b, v, 3, 3))


class Poser:
    """Precomputed per-character state of the posing path (weights, rest mesh, cluster axes).

    Args:
        character: a :class:`prt_torch.rig.Character`.
        cluster: ``(V,)`` cluster labels; cluster_axis: ``(Kc, 3)``; cluster_bone: ``(Kc,)`` (the
            dataset's frame data, as in :func:`prt_torch.bake.frames.local_frames`).
    """

    def __init__(self, character, cluster: np.ndarray, cluster_axis: np.ndarray, cluster_bone: np.ndarray) -> None:
        from prt_torch.bake.frames import FALLBACK_BELOW, fallback_axes

        self.character = character
        v = character.num_vertices
        cluster = np.asarray(cluster)
        check(cluster.shape == (v,), f"cluster labels must be ({v},), got {cluster.shape}")
        axes = np.asarray(cluster_axis, dtype=np.float64)
        bones = np.asarray(cluster_bone).astype(np.intp)
        check(axes.ndim == 2 and axes.shape[1] == 3 and bones.shape == (axes.shape[0],)
              and int(cluster.max()) < axes.shape[0], "cluster axes / bones do not match the cluster labels")
        self.labels = cluster.astype(np.intp)
        self.axes = axes
        self.fallback = fallback_axes(axes)
        self.bones = bones
        self.fallback_below = np.float32(FALLBACK_BELOW)
        self.w_t = np.ascontiguousarray(character.dense_weights.T, dtype=np.float32)  # (J, V)
        self.rest = np.ascontiguousarray(character.rest_vertices.T, dtype=np.float32)  # (3, V)
        self.rest_n = np.ascontiguousarray(character.rest_normals.T, dtype=np.float32)
        self.n_vertices = v

    def __call__(self, local: np.ndarray, eye: np.ndarray) -> PoseBatch:
        """Pose ``local (B, J, 4, 4)`` joint transforms; ``eye (3,)`` camera position for the view directions."""
        from prt_torch.rig.features import pose_features
        from prt_torch.rig.skeleton import forward_kinematics

        ch = self.character
        local = np.asarray(local, dtype=np.float64)
        if local.ndim != 4 or local.shape[1:] != (ch.num_joints, 4, 4) or local.shape[0] < 1:
            raise PrtError(f"local joint transforms must be (B, {ch.num_joints}, 4, 4) with B >= 1, got {local.shape}")
        if not np.isfinite(local).all():
            raise PrtError("local joint transforms contain NaN or Inf")
        b = local.shape[0]
        skin = forward_kinematics(ch.parents, local) @ ch.inverse_bind[None]  # (B, J, 4, 4) float64
        rows = skin[:, :, :3, :].reshape(b, -1, 12).transpose(0, 2, 1).astype(np.float32)  # (B, 12, J)
        blend = rows @ self.w_t  # (B, 12, V): blended 3x4 matrix entries, vertex-last
        x, y, z = self.rest
        nx, ny, nz = self.rest_n
        pos = np.empty((b, 3, self.n_vertices), np.float32)
        nrm = np.empty_like(pos)
        for i in range(3):
            r = 4 * i
            pos[:, i] = blend[:, r] * x + blend[:, r + 1] * y + blend[:, r + 2] * z + blend[:, r + 3]
            nrm[:, i] = blend[:, r] * nx + blend[:, r + 1] * ny + blend[:, r + 2] * nz
        nrm *= 1.0 / np.maximum(np.sqrt(np.einsum("biv,biv->bv", nrm, nrm)), 1e-12)[:, None, :]
        # cluster axes carried by their bones, gathered per vertex
        rot = skin[:, self.bones, :3, :3]  # (B, Kc, 3, 3)
        a_c = np.einsum("bkij,kj->bki", rot, self.axes)
        p_c = np.einsum("bkij,kj->bki", rot, self.fallback)
        a_c /= np.maximum(np.linalg.norm(a_c, axis=-1, keepdims=True), 1e-12)
        p_c /= np.maximum(np.linalg.norm(p_c, axis=-1, keepdims=True), 1e-12)
        a = a_c.transpose(0, 2, 1).astype(np.float32)[:, :, self.labels]  # (B, 3, V)
        p = p_c.transpose(0, 2, 1).astype(np.float32)[:, :, self.labels]
        ta = a - np.einsum("biv,biv->bv", a, nrm)[:, None] * nrm
        tp = p - np.einsum("biv,biv->bv", p, nrm)[:, None] * nrm
        la = np.sqrt(np.einsum("biv,biv->bv", ta, ta))
        w = np.clip(1.0 - la / self.fallback_below, 0.0, 1.0)
        t = ta + w[:, None] * tp
        lt = np.sqrt(np.einsum("biv,biv->bv", t, t))
        if (lt < 1e-6).any():  # measure-zero coincidence: use the reference implementation there
            t = self._degenerate(t, nrm, lt)
            lt = np.sqrt(np.einsum("biv,biv->bv", t, t))
        t /= lt[:, None]
        frames = np.empty((b, 9, self.n_vertices), np.float32)
        frames[:, 0:3] = t
        frames[:, 3] = nrm[:, 1] * t[:, 2] - nrm[:, 2] * t[:, 1]  # b = n x t
        frames[:, 4] = nrm[:, 2] * t[:, 0] - nrm[:, 0] * t[:, 2]
        frames[:, 5] = nrm[:, 0] * t[:, 1] - nrm[:, 1] * t[:, 0]
        frames[:, 6:9] = nrm
        view = np.asarray(eye, dtype=np.float32).reshape(1, 3, 1) - pos
        view *= 1.0 / np.maximum(np.sqrt(np.einsum("biv,biv->bv", view, view)), 1e-12)[:, None, :]
        feats = pose_features(local, ch.bind_local, ch.parents)
        return PoseBatch(pos, nrm, frames, view, np.ascontiguousarray(feats, dtype=np.float32))

    @staticmethod
    def _degenerate(t: np.ndarray, nrm: np.ndarray, lt: np.ndarray) -> np.ndarray:
        t = t.copy()
        bi, vi = np.nonzero(lt < 1e-6)
        n = nrm[bi, :, vi]  # (m, 3)
        alt = np.cross(n, np.eye(3, dtype=np.float32)[np.argmin(np.abs(n), axis=-1)])
        t[bi, :, vi] = alt
        return t

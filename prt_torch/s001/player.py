"""Run-time evaluation of seed 001 (sec. 5, eq. 8-9): interpolated PCA coefficients shaded in the paper's order.

Numpy (+ scipy's k-d tree through :mod:`prt_torch.s001.posespace`); no torch in this module.

Shading (eq. 5): ``Gamma = V^T B T L`` with ``B = H G^T`` (``H, G (C, n_t)``, the SVD factors of the SH-projected
BRDF matrix, :mod:`prt_torch.s001.brdf_matrix`), ``V = y(w_o)`` the SH basis at the local view direction
(``w_o = frames @ normalize(eye - p)``, frames rows ``t, b, n``), ``T (C, C)`` the local-frame transfer matrix and
``L (C, 3)`` the global SH lighting (RGB). With ``T = M_m + sum_i lambda_i U_i`` (cluster ``m``'s mean and basis,
eq. 7) the evaluation order of eq. 9 is

    Q_i = G^T U_i                 (n_t, C)     once per BRDF          (:meth:`S001Player.set_shading`)
    S_i = Q_i L                   (n_t, 3)     once per lighting      (mean included as i = 0)
    Z   = S_0 + sum_i lambda_i S_i (n_t, 3)    per vertex and frame
    Gamma = (V^T H) Z             (3,)         per vertex and frame

``scheme = "s001"``: per segment, the normalized-cut pose group of the nearest sampled pose (all its poses share the
row's PCA cluster, so ``lambda`` is interpolated first, eq. 7); ``"posespace"``: the same nearest sampled poses for
the whole body, whose PCA clusters differ per pose, so ``Z = sum_l alpha_l (S_0 + sum_i c_li S_i)`` over the
neighbours' own clusters (eq. 6 form).
"""

from __future__ import annotations

from typing import Literal

import numpy as np

from prt_torch.errors import check
from prt_torch.s001.posespace import CompressedTransfer, segment_rotations
from prt_torch.shapes import check_shape

SCHEMES = ("s001", "posespace")


class S001Player:
    """Interpolate and shade the compressed transfer matrices of a run (module doc)."""

    def __init__(self, data: CompressedTransfer, scheme: Literal["s001", "posespace"] = "s001") -> None:
        check(scheme in SCHEMES, f"unknown scheme {scheme!r}: expected one of {', '.join(SCHEMES)}")
        self.data = data
        self.scheme = scheme
        self.space = data.posespace()
        self.order = int(round(np.sqrt(data.n_coeffs)))
        c = data.n_coeffs
        m, nb, _ = data.basis.shape
        # mean as basis 0: (M, nb + 1, C, C)
        self._u = np.concatenate([data.mean[:, None], data.basis], axis=1).reshape(m, nb + 1, c, c)
        self._v = np.arange(data.n_vertices)
        # (PCA cluster, segment) pairs: a cluster may serve several segments, each with its own rotated lighting
        k = self.space.n_segments
        code = data.vertex_cluster.astype(np.int64) * k + data.segment[None]  # (G, V)
        uniq, inv = np.unique(code, return_inverse=True)
        self._pair_of = inv.reshape(code.shape)
        self._pair_cluster, self._pair_segment = uniq // k, uniq % k
        self._h: dict[str, np.ndarray] = {}
        self._q: dict[str, np.ndarray] = {}
        self._light = np.zeros((c, 3))

    # -- precompute ---------------------------------------------------------------------------------------------
    def set_shading(self, brdfs: dict[str, tuple[np.ndarray, np.ndarray]], light: np.ndarray) -> None:
        """``brdfs {name: (H (C, n_t), G (C, n_t))}`` and the global SH lighting ``light (C, 3)``: precomputes
        ``Q_i = G^T U_i`` per PCA cluster and basis (``(M, nb + 1, n_t, C)`` per BRDF)."""
        c = self.data.n_coeffs
        light = np.asarray(light, dtype=np.float64)
        check_shape(light, (c, 3), name="SH lighting")
        self._light = light
        self._h, self._q = {}, {}
        for name, (h, g) in brdfs.items():
            h, g = np.asarray(h, np.float64), np.asarray(g, np.float64)
            dims = check_shape(h, (c, "n_t"), name=f"BRDF {name!r}: H")
            check_shape(g, (c, "n_t"), name=f"BRDF {name!r}: G", dims=dims)
            self._q[name] = np.einsum("ct,mbcd->mbtd", g, self._u).astype(np.float32)  # Q_i = G^T U_i
            self._h[name] = h.astype(np.float32)

    def rotations(self, frames: np.ndarray) -> np.ndarray:
        """``D(R_k) (K, C, C)`` float64 of a frame's segments (``frames (V, 3, 3)``; :func:`segment_rotations`)."""
        from prt_torch.sh.rotation import sh_rotation

        r = segment_rotations(frames, self.data.ref_frames, self.data.segment, self.space.n_segments)
        return np.asarray(sh_rotation(r, self.order))

    # -- per frame ----------------------------------------------------------------------------------------------
    def neighbours(self, pose: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Per-vertex sampled poses ``idx (V, L)`` and NRBF weights ``alpha (V, L)`` of the scheme."""
        if self.scheme == "s001":
            idx, alpha = self.space.segment_neighbours(pose)
            seg = self.data.segment
            return idx[seg], alpha[seg]
        idx, alpha = self.space.global_neighbours(pose)
        v = self.data.n_vertices
        return np.broadcast_to(idx, (v, len(idx))), np.broadcast_to(alpha, (v, len(alpha)))

    def _weights(self, pose: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Per vertex and neighbour: the (PCA cluster, segment) pair ``(V, L)`` and the weights of the cluster's
        ``nb + 1`` basis rows ``(V, L, nb + 1)`` (column 0 = the mean, weight ``alpha``). For ``s001`` (one cluster
        per row) ``L = 1`` and the weights are ``(1, lambda)`` (eq. 7)."""
        d = self.data
        idx, alpha = self.neighbours(pose)
        v = self._v[:, None]
        g = d.groups[d.segment[v], idx]  # (V, L) pose group of each neighbour
        cl = d.vertex_cluster[g, v]
        pair = self._pair_of[g, v]
        if self.scheme == "s001":
            cl0 = cl[:, 0]
            q = d.coeff_q[idx, v].astype(np.float32)  # (V, L, nb)
            lam = d.coeff_offset[cl0] + d.coeff_scale[cl0] * np.einsum("vl,vlb->vb", alpha.astype(np.float32), q)
            w = np.concatenate([np.ones((len(cl0), 1), np.float32), lam], axis=1)
            return pair[:, :1], w[:, None]
        c = d.coefficients(idx)  # (V, L, nb) each pose in its own cluster
        a = alpha.astype(np.float32)[..., None]
        return pair, np.concatenate([a, a * c], axis=-1)

    def transfer(self, pose: np.ndarray, frames: np.ndarray) -> np.ndarray:
        """The interpolated transfer matrices ``(V, C, C)`` float32 of a pose in the store's convention (global light
        columns): ``T = (sum_l w_l U_l) D(R_k)^T`` (eq. 6 / 7, then the segment rotation)."""
        pair, w = self._weights(pose)
        tk = np.einsum("vlb,vlbcd->vcd", w, self._u[self._pair_cluster[pair]])
        d = self.rotations(frames)[self.data.segment]  # (V, C, C)
        return np.einsum("vcd,ved->vce", tk, d).astype(np.float32)

    def radiance(self, pose: np.ndarray, frames: np.ndarray, positions: np.ndarray,
                 eye: np.ndarray) -> dict[str, np.ndarray]:
        """Outgoing radiance ``{brdf: (V, 3)}`` float32 toward ``eye`` (eq. 9 order, module doc)."""
        from prt_torch.sh.basis import sh_basis

        check(self._q, "S001Player.set_shading must be called before radiance")
        v = self.data.n_vertices
        frames = np.asarray(frames, np.float32)
        positions = np.asarray(positions, np.float32)
        check_shape(frames, (v, 3, 3), name="frames")
        check_shape(positions, (v, 3), name="positions")
        pair, w = self._weights(pose)
        # the lighting in each segment's reference frame, D(R_k)^T L: (K, C, 3), then per (cluster, segment) pair
        lk = np.einsum("kdc,dj->kcj", self.rotations(frames), self._light).astype(np.float32)
        lm = lk[self._pair_segment]  # (N, C, 3)
        view = np.asarray(eye, np.float32)[None] - positions
        view /= np.maximum(np.linalg.norm(view, axis=1, keepdims=True), 1e-12)
        wo = np.einsum("vij,vj->vi", frames, view).astype(np.float64)
        wo /= np.maximum(np.linalg.norm(wo, axis=1, keepdims=True), 1e-12)
        y = np.asarray(sh_basis(wo, self.order), np.float32)  # (V, C) SH at the local view direction
        out = {}
        for name, q in self._q.items():
            s = np.einsum("mbtc,mck->mbtk", q[self._pair_cluster], lm)  # S_i = Q_i L per pair (N, nb + 1, n_t, 3)
            z = np.einsum("vlb,vlbtk->vtk", w, s[pair])  # Z (V, n_t, 3)
            vh = y @ self._h[name]  # V^T H (V, n_t)
            out[name] = np.einsum("vt,vtk->vk", vh, z)
        return out

"""The player's compiled CPU frame path: the fused graph's numbers in one compiled pass over the mesh.

Per frame, for ``B`` characters of one run (:class:`CompiledFrame`)::

    pose features (B, A) --ORT latent.onnx--> z (B, G, K)            the model up to its output bases (~40 kB)
    z --quantize_latent--> int8 latent per block (as MatMulNBits)    tiny, serial
    decode_shade_pass: per tile of <= TILE vertices of one cluster   numba threads over tiles
        visibility (C, T) = basis_g^T z_g + mean                     each basis column read once for all B
        radiance (B, T, 3) = RPO shading under the ZH lobes          while the tile is in cache
    -> radiance (B, V, 3) in the ORIGINAL vertex order               the only array written

with the posing in one compiled pass too (:class:`CompiledPoser`: LBS from the non-zero skin weights, vertex frames,
view directions). The ONNX graphs stay the shipped contract: this path equals ``fused.onnx`` within the export's
parity tolerance (``tests/player/test_compiled.py``), and it is the player's default on the CPU
(:func:`prt_torch.player.player.default_graph`). Data: ``latent.onnx`` and ``decode.npz``
(:mod:`prt_torch.export.compiled`); numpy + numba + onnxruntime, no torch.
"""

from __future__ import annotations

from typing import Any

import numba
import numpy as np

from prt_torch.errors import MissingArtifact, PrtError, check
from prt_torch.player.bundle import RPOTensors, RunBundle
from prt_torch.player.frame_kernels import TILE, decode_shade_pass, pose_pass, quantize_latent, skeleton_pass
from prt_torch.player.posing import PoseBatch, Poser
from prt_torch.runtime.session import OrtGraph
from prt_torch.sh.basis import band_of
from prt_torch.shapes import check_shape

#: ``decode.npz``'s layout this player reads (:data:`prt_torch.export.compiled.DECODE_FORMAT`)
DECODE_FORMAT = 1
#: thread tasks (runs of consecutive tiles) per numba thread in the decode + shade pass
TASKS_PER_THREAD = 4
#: largest ``|M - Gamma u| / max |M|`` accepted for an RPO played in its product form (float32 rounding of ``M``)
PRODUCT_FORM_RTOL = 1e-5


def has_compiled_path(bundle: RunBundle) -> bool:
    """Whether the run's export ships the compiled frame path's data (``export.json``'s ``compiled`` entry)."""
    return isinstance(bundle.meta.get("compiled"), dict) and bundle.vertex_order is not None


class CompiledFrame:
    """Decode + shade of a run's characters in one compiled pass (module doc).

    Args:
        bundle: the run's :class:`~prt_torch.player.bundle.RunBundle` (its export verified: ``latent.onnx`` and
            ``decode.npz`` have the sha256 ``export.json`` records).
        threads: onnxruntime intra-op threads of the latent graph.
        spinning: let those threads busy-wait.
    """

    def __init__(self, bundle: RunBundle, threads: int = 2, spinning: bool = False) -> None:
        run = bundle.run
        if not has_compiled_path(bundle):
            raise MissingArtifact(f"{run.path}: the export has no compiled frame path ({run.latent_graph_path.name}, "
                                  f"{run.decode_path.name}): run `prt export {run.path} --force`")
        self.order = bundle.order
        c = self.order * self.order
        v = bundle.n_vertices
        self.latent = OrtGraph(run.latent_graph_path, threads=threads, spinning=spinning)
        with np.load(run.decode_path, allow_pickle=False) as z:
            d = {k: z[k] for k in z.files}
        check(int(d["format"]) == DECODE_FORMAT, f"{run.decode_path}: layout {int(d['format'])}, this player reads "
                                                 f"{DECODE_FORMAT}: run `prt export {run.path} --force`")
        check(int(d["n_coeffs"]) == c and d["mean"].shape == (c, v) and int(d["n_used"].sum()) == v,
              f"{run.decode_path}: does not match the run ({c} coefficients, {v} vertices)")
        self.int8 = str(d["precision"]) == "int8"
        i64 = np.int64
        self.rows = d["clusters"].astype(i64)
        self.starts, self.n_used = d["starts"].astype(i64), d["n_used"].astype(i64)
        self.k_used, self.blocks = d["k_used"].astype(i64), d["blocks"].astype(i64)
        self.q, self.scales, self.q_off, self.s_off = k_major(d, c)
        self.weights = d.get("weights", np.zeros(0, np.float32)).astype(np.float32)
        self.mean = np.ascontiguousarray(d["mean"], dtype=np.float32)
        blk = np.maximum(self.blocks, 1)
        n_blocks = np.where(self.blocks > 0, -(-self.k_used // blk), 1)
        self.k_pad = int(max(1, (n_blocks * np.where(self.blocks > 0, self.blocks, 0)).max(initial=0),
                             self.k_used.max(initial=0)))
        self.nb_max = int(n_blocks.max(initial=1))
        self.tile_start, self.tile_end, self.tile_group = tiles(self.starts, self.n_used, TILE)
        self.vertex_order = np.ascontiguousarray(bundle.vertex_order, dtype=np.int64)
        self.n_vertices = v
        from prt_torch.sh.polynomial import monomial_recursion
        from prt_torch.sh.product import dense_gaunt

        _, self.parent, self.comp, coeffs_t = monomial_recursion(self.order)
        self.coeffs_t = coeffs_t
        sc, sp = np.nonzero(coeffs_t)
        self.sh_c, self.sh_p, self.sh_v = sc.astype(i64), sp.astype(i64), coeffs_t[sc, sp].astype(np.float32)
        self.gaunt = dense_gaunt(self.order)
        gi, gj, gk = np.nonzero(self.gaunt)
        self.g_i, self.g_j, self.g_k = gi.astype(i64), gj.astype(i64), gk.astype(i64)
        self.g_v = self.gaunt[gi, gj, gk].astype(np.float32)
        self.band = band_of(self.order)
        self._rpo_cache: dict[int, tuple[RPOTensors, np.ndarray, np.ndarray]] = {}

    def bytes(self) -> int:
        """Bytes the decode reads per frame: the bases (int8 + scales, or float32) and the mean."""
        return int(self.q.nbytes + self.scales.nbytes + self.weights.nbytes + self.mean.nbytes)

    def decode_macs(self) -> int:
        """Multiply-adds of the decode per character: ``k_used * C * n_used`` summed over the clusters."""
        return int((self.k_used * self.n_used).sum()) * self.order * self.order

    def rpo_tables(self, rpo: RPOTensors) -> tuple[np.ndarray, np.ndarray]:
        """``(wm (k, P), u (k, C))`` float32 of ``rpo``: its view factors on the monomials and its light factors,
        checked once against its ``M`` (``M_b = sum_k u_bk Gamma_{., ., k}``, one-line error otherwise)."""
        hit = self._rpo_cache.get(id(rpo))
        if hit is not None and hit[0] is rpo:
            return hit[1], hit[2]
        m_prod = np.einsum("bk,ijk->bij", rpo.u.astype(np.float64), self.gaunt)
        scale = max(float(np.abs(rpo.M).max()), 1e-30)
        err = float(np.abs(m_prod - rpo.M).max()) / scale
        if err > PRODUCT_FORM_RTOL:
            raise PrtError(f"RPO {rpo.name!r}: M is not the product matrix of its light factors u (rel. error "
                           f"{err:.2g}): play it with graph 'fused'")
        wm = np.ascontiguousarray(rpo.w.astype(np.float64) @ self.coeffs_t, dtype=np.float32)
        u = np.ascontiguousarray(rpo.u, dtype=np.float32)
        self._rpo_cache[id(rpo)] = (rpo, wm, u)
        return wm, u

    def radiance(self, features: np.ndarray, frames: np.ndarray, view_dirs: np.ndarray, lobe_dirs: np.ndarray,
                 lobe_coeffs: np.ndarray, rpo: RPOTensors) -> np.ndarray:
        """Radiance ``(B, V, 3)`` float32 in the ORIGINAL vertex order of ``B`` characters: ``features (B, A)``,
        ``frames (B, 9, V)`` and ``view_dirs (B, 3, V)`` in the export's cluster-sorted order, the lighting's ZH lobes
        ``lobe_dirs (L, 3)``, ``lobe_coeffs (L, n, 3)``, and ``rpo``: what ``fused.onnx`` returns for the same inputs
        (then put back in the original order)."""
        b = features.shape[0]
        check_shape(frames, (b, 9, self.n_vertices), name="frames")
        check_shape(view_dirs, (b, 3, self.n_vertices), name="view directions")
        z = self.latent.run_unchecked({"pose": np.ascontiguousarray(features, dtype=np.float32)})[0]
        zq, zs = quantize_latent(np.ascontiguousarray(z, dtype=np.float32), self.rows, self.k_used,
                                 self.blocks if self.int8 else np.zeros_like(self.blocks), self.k_pad, self.nb_max)
        wm, u = self.rpo_tables(rpo)
        lobe_g = np.ascontiguousarray(np.asarray(lobe_coeffs, np.float32)[:, self.band], dtype=np.float32)
        out = np.empty((b, self.n_vertices, 3), np.float32)
        decode_shade_pass(zq, zs, self.tile_start, self.tile_end, self.tile_group, self.starts, self.n_used,
                          self.k_used, self.blocks if self.int8 else np.zeros_like(self.blocks), self.q_off,
                          self.s_off, self.q, self.scales, self.weights, self.mean,
                          np.ascontiguousarray(frames, dtype=np.float32),
                          np.ascontiguousarray(view_dirs, dtype=np.float32),
                          np.ascontiguousarray(lobe_dirs, dtype=np.float32), lobe_g, wm, u, self.g_i, self.g_j,
                          self.g_k, self.g_v, self.parent, self.comp, self.sh_c, self.sh_p, self.sh_v,
                          np.ascontiguousarray(rpo.tint, dtype=np.float32), self.vertex_order, out,
                          min(len(self.tile_start), TASKS_PER_THREAD * numba.get_num_threads()))
        return out


def k_major(d: dict[str, np.ndarray], c: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``decode.npz``'s int8 bases (column-major blocks, the ONNX layout) rewritten k-major for the kernel:
    ``(q, scales, q_offsets, scale_offsets)`` with cluster ``g``'s ``(k_used, C n_g)`` int8 basis and ``(NB_g, C n_g)``
    scales at their offsets; float32 bases are k-major already (their offsets returned as stored)."""
    if "q" not in d:
        return np.zeros(0, np.int8), np.zeros(0, np.float32), d["q_offsets"].astype(np.int64), \
            np.zeros_like(d["q_offsets"], dtype=np.int64)
    qs, ss, q_off, s_off = [], [], [], []
    at_q = at_s = 0
    for g in range(len(d["n_used"])):
        n_cols, kg, blk = c * int(d["n_used"][g]), int(d["k_used"][g]), int(d["blocks"][g])
        nb = -(-kg // blk) if blk else 0
        q = d["q"][d["q_offsets"][g]:d["q_offsets"][g] + n_cols * nb * blk].reshape(n_cols, nb * blk)
        s = d["scales"][d["scale_offsets"][g]:d["scale_offsets"][g] + n_cols * nb].reshape(n_cols, nb)
        qs.append(np.ascontiguousarray(q[:, :kg].T).reshape(-1))
        ss.append(np.ascontiguousarray(s.T).reshape(-1))
        q_off.append(at_q)
        s_off.append(at_s)
        at_q += qs[-1].size
        at_s += ss[-1].size
    return (np.concatenate(qs).astype(np.int8), np.concatenate(ss).astype(np.float32),
            np.asarray(q_off, np.int64), np.asarray(s_off, np.int64))


def tiles(starts: np.ndarray, n_used: np.ndarray, size: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(start, end, group)`` int64 of the tiles of at most ``size`` consecutive vertices that cover each group's
    vertices ``starts[g] .. starts[g] + n_used[g]`` (a tile never spans two groups)."""
    counts = -(-n_used // size)
    group = np.repeat(np.arange(len(n_used)), counts)
    first = np.repeat(np.cumsum(counts) - counts, counts)
    k = np.arange(len(group)) - first
    start = starts[group] + k * size
    end = np.minimum(start + size, starts[group] + n_used[group])
    return start.astype(np.int64), end.astype(np.int64), group.astype(np.int64)


class CompiledPoser(Poser):
    """A :class:`~prt_torch.player.posing.Poser` in two compiled passes: FK, skinning matrices and pose features over
    the joints (:func:`~prt_torch.player.frame_kernels.skeleton_pass`), then LBS from each vertex's non-zero skin
    weights, vertex frames and view directions over the vertices (:func:`~prt_torch.player.frame_kernels.pose_pass`).
    Same outputs as the numpy poser within float32 rounding (tests/player/test_compiled.py)."""

    def __init__(self, character: Any, cluster: np.ndarray, cluster_axis: np.ndarray, cluster_bone: np.ndarray,
                 order: np.ndarray | None = None) -> None:
        super().__init__(character, cluster, cluster_axis, cluster_bone, order=order)
        w = np.ascontiguousarray(self.w_t.T)  # (V, J) in the posing order
        rows, cols = np.nonzero(w)
        self.indptr = np.concatenate([[0], np.cumsum(np.bincount(rows, minlength=w.shape[0]))]).astype(np.int64)
        self.joint = cols.astype(np.int64)
        self.weight = w[rows, cols].astype(np.float32)
        self.labels64 = self.labels.astype(np.int64)
        from prt_torch.rig.rotations import rotation_part

        ch = character
        self.parents = np.asarray(ch.parents, np.int64)
        self.inverse_bind = np.ascontiguousarray(ch.inverse_bind, dtype=np.float64)
        self.bind_rot_t = np.ascontiguousarray(np.swapaxes(rotation_part(ch.bind_local), -1, -2))
        self.feature_joints = np.flatnonzero(self.parents >= 0).astype(np.int64)  # pose_features(exclude_root)

    def bytes(self) -> int:
        """Bytes the vertex pass reads per call: the sparse skin weights, the rest mesh and the labels."""
        return int(self.indptr.nbytes + self.joint.nbytes + self.weight.nbytes + self.rest.nbytes + self.rest_n.nbytes
                   + self.labels64.nbytes)

    def __call__(self, local: np.ndarray, eye: np.ndarray, features: np.ndarray | None = None) -> PoseBatch:
        local = self.checked_local(local)
        b = local.shape[0]
        skin = np.empty(local.shape)  # (B, J, 4, 4) float64
        feats = np.empty((b, 6 * len(self.feature_joints)), np.float32)
        if not skeleton_pass(self.parents, local, self.inverse_bind, self.bind_rot_t, self.feature_joints, skin,
                             feats):
            raise PrtError("transform has a zero scale: cannot extract its rotation")
        rows = np.ascontiguousarray(skin[:, :, :3, :].reshape(b, -1, 12), dtype=np.float32)
        carried = np.einsum("bkij,mkj->bmik", skin[:, self.bones, :3, :3], self.axes2)  # (B, 2, 3, Kc)
        carried /= np.maximum(np.sqrt((carried * carried).sum(axis=2, keepdims=True)), 1e-12)
        v = self.n_vertices
        pos, nrm, view = (np.empty((b, 3, v), np.float32) for _ in range(3))
        frames = np.empty((b, 9, v), np.float32)
        pose_pass(rows, self.indptr, self.joint, self.weight, self.rest, self.rest_n, self.labels64,
                  np.ascontiguousarray(carried, dtype=np.float32), np.asarray(eye, np.float32).reshape(3), pos, nrm,
                  frames, view)
        return PoseBatch(pos, nrm, frames, view, feats if features is None else features, order=self.order, skin=skin)

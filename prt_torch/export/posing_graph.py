"""The per-frame posing path (FK, LBS, vertex frames, view directions, pose features) as a torch graph for ONNX.

A measurement of issue 14 item 3 ("move the posing into the ONNX graph, one ORT call per frame"): the same
rule as the player's numpy :class:`prt_torch.player.posing.Poser` (vertex-last float32 rows), written once in
torch so that it exports with :func:`prt_torch.export.onnx_file.export_onnx`; the tests check the ONNX file
against the numpy Poser. It reuses the rig's rules and constants (:func:`~prt_torch.rig.vertex_frames.fallback_axes`,
:data:`~prt_torch.rig.vertex_frames.FALLBACK_BELOW`, :data:`~prt_torch.rig.vertex_frames.DEGENERATE_BELOW`, the
6D features of :mod:`prt_torch.rig.features`), computed in float32 (the Poser runs FK in float64).

Inputs: ``local (B, J, 4, 4)`` float32 local joint transforms, ``eye (3,)`` float32 camera position.
Outputs (:data:`POSING_OUTPUTS`): ``positions (B, 3, V)``, ``normals (B, 3, V)`` (unit), ``frames (B, 9, V)``
(entry ``3i + j`` is ``F[i, j]``, rows ``(t, b, n)``), ``view_dirs (B, 3, V)`` (unit, vertex -> eye),
``features (B, A)``; vertices in the graph's ``order`` (position ``i`` holds original vertex ``order[i]``).

FK runs by pointer doubling: ``ceil(log2(depth + 1))`` steps (3-4 for a humanoid) of one gather of each joint's
current ancestor link and one batched 4x4 matmul, instead of one node per joint or per depth level.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import torch
from torch import nn

from prt_torch.errors import check
from prt_torch.rig.rotations import rotation_part
from prt_torch.rig.skeleton import check_parents
from prt_torch.rig.vertex_frames import DEGENERATE_BELOW, FALLBACK_BELOW, fallback_axes
from prt_torch.shapes import check_shape

POSING_INPUTS = ("local", "eye")
POSING_OUTPUTS = ("positions", "normals", "frames", "view_dirs", "features")


def _sum3(x: torch.Tensor) -> torch.Tensor:
    """Sum over the size-3 axis ``-2`` of ``(..., 3, V)``, keeping it: a ``(1, 3)`` GEMM (ORT's ReduceSum over a
    middle axis measured ~3x slower)."""
    return torch.ones(1, 3, dtype=x.dtype) @ x


def _unit(x: torch.Tensor) -> torch.Tensor:
    """``x (..., 3, V)`` normalised along axis ``-2`` (lengths clamped at 1e-12, as the Poser)."""
    return x / torch.clamp(torch.sqrt(_sum3(x * x)), min=1e-12)


class PosingGraph(nn.Module):
    """The posing path as one graph (see module docstring).

    Args:
        character: a :class:`prt_torch.rig.Character`.
        cluster, cluster_axis, cluster_bone: ``(V,)`` labels, ``(Kc, 3)`` rest axes, ``(Kc,)`` dominant bones (the
            dataset's frame data, as the Poser takes them).
        order: ``(V,)`` vertex permutation the graph works in (the fused graph's cluster-sorted order); ``None``:
            the original order.
    """

    def __init__(self, character, cluster: np.ndarray, cluster_axis: np.ndarray, cluster_bone: np.ndarray,
                 order: np.ndarray | None = None) -> None:
        super().__init__()
        ch = character
        v = ch.num_vertices
        cluster = np.asarray(cluster).astype(np.int64)
        axes = np.asarray(cluster_axis, dtype=np.float64)
        bones = np.asarray(cluster_bone).astype(np.int64)
        check_shape(cluster, (v,), name="cluster labels")
        check(axes.ndim == 2 and axes.shape[1] == 3 and bones.shape == (axes.shape[0],)
              and int(cluster.max()) < axes.shape[0], "cluster axes / bones do not match the cluster labels")
        sel = np.arange(v) if order is None else np.asarray(order).astype(np.int64)
        check(sel.shape == (v,) and np.array_equal(np.sort(sel), np.arange(v)),
              f"vertex order must be a permutation of {v} vertices")
        parents = check_parents(ch.parents)
        self.n_joints = int(parents.size)
        # FK by pointer doubling: after step s every joint holds the product of its 2^s nearest chain links;
        # index J is an identity (the roots' "parent"): ceil(log2(depth + 1)) steps of one Gather + one MatMul
        anc = np.where(parents < 0, parents.size, parents)
        steps = []
        while (anc < parents.size).any():
            steps.append(anc.copy())
            anc = np.append(anc, parents.size)[anc]
        self.n_steps = len(steps)
        for i, a in enumerate(steps):
            self.register_buffer(f"_anc{i}", torch.from_numpy(a))
        f32 = lambda a: torch.from_numpy(np.ascontiguousarray(a, dtype=np.float32))  # noqa: E731
        self.register_buffer("inverse_bind", f32(ch.inverse_bind))  # (J, 4, 4)
        self.register_buffer("w_t", f32(ch.dense_weights.T[:, sel]))  # (J, V)
        self.register_buffer("rest", f32(ch.rest_vertices.T[:, sel]))  # (3, V)
        self.register_buffer("rest_n", f32(ch.rest_normals.T[:, sel]))  # (3, V)
        # cluster -> vertex broadcast as a one-hot GEMM (exact: one 1 per column); ORT's Gather along the
        # innermost axis measured ~10x slower than this (Kc, V) GEMM
        self.register_buffer("onehot", f32(np.eye(axes.shape[0])[:, cluster[sel]]))  # (Kc, V)
        self.register_buffer("bones", torch.from_numpy(bones))  # (Kc,)
        self.register_buffer("axes2", f32(np.stack([axes, fallback_axes(axes)])))  # (2, Kc, 3)
        keep = np.flatnonzero(parents >= 0)  # pose features: non-root joints
        self.register_buffer("feat_joints", torch.from_numpy(keep))
        self.register_buffer("bind_rel_t", f32(np.swapaxes(rotation_part(ch.bind_local), -1, -2)[keep]))  # (J', 3, 3)
        self.n_vertices = v
        self.register_buffer("yzx", torch.tensor([1, 2, 0]))
        self.register_buffer("zxy", torch.tensor([2, 0, 1]))

    def _cross(self, a_yzx: torch.Tensor, a_zxy: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
        """``a x b`` along axis 1 of ``(B, 3, V)`` from ``a``'s cyclic permutations (shared between products)."""
        return a_yzx * b.index_select(1, self.zxy) - a_zxy * b.index_select(1, self.yzx)

    def forward(self, local: torch.Tensor, eye: torch.Tensor) -> tuple[torch.Tensor, ...]:
        b = local.shape[0]
        # FK by pointer doubling (see __init__): world_j = local_root ... local_j
        world = local
        eye4 = torch.eye(4, dtype=local.dtype).expand(b, 1, 4, 4)
        for i in range(self.n_steps):
            world = torch.cat([world, eye4], 1).index_select(1, getattr(self, f"_anc{i}")) @ world
        skin = world @ self.inverse_bind  # (B, J, 4, 4)
        # LBS, vertex-last: (B, 12, J) @ (J, V) -> blended 3x4 entries
        rows = skin[:, :, :3, :].reshape(b, self.n_joints, 12).transpose(1, 2)
        bm = (rows @ self.w_t).reshape(b, 3, 4, -1)  # (B, 3, 4, V)
        r = self.rest
        rn = self.rest_n
        pos = bm[:, :, 0] * r[0] + bm[:, :, 1] * r[1] + bm[:, :, 2] * r[2] + bm[:, :, 3]
        nrm = _unit(bm[:, :, 0] * rn[0] + bm[:, :, 1] * rn[1] + bm[:, :, 2] * rn[2])
        # vertex frames (rule of prt_torch.rig.vertex_frames)
        rot = skin.index_select(1, self.bones)[:, :, :3, :3]  # (B, Kc, 3, 3)
        ap = _unit(torch.einsum("bkij,mkj->bmik", rot, self.axes2))  # (B, 2, 3, Kc)
        ap = (ap.reshape(b, 6, -1) @ self.onehot).reshape(b, 2, 3, -1)  # (B, 2, 3, V)
        n1 = nrm.unsqueeze(1)
        tan = ap - _sum3(ap * n1) * n1  # tangents of axis and fallback
        ta, tp = tan[:, 0], tan[:, 1]
        la = torch.sqrt(_sum3(ta * ta))
        w = torch.clamp(1.0 - la / FALLBACK_BELOW, 0.0, 1.0)
        t = ta + w * tp
        lt = torch.sqrt(_sum3(t * t))
        # measure-zero coincidence: n x (least aligned world axis), as the reference does
        a = nrm.abs()
        ex = (a[:, 0:1] <= a[:, 1:2]) & (a[:, 0:1] <= a[:, 2:3])
        ey = ~ex & (a[:, 1:2] <= a[:, 2:3])
        ez = ~ex & ~ey
        e = torch.cat([ex, ey, ez], 1).to(nrm.dtype)
        n_yzx, n_zxy = nrm.index_select(1, self.yzx), nrm.index_select(1, self.zxy)
        alt = self._cross(n_yzx, n_zxy, e)
        t = torch.where(lt < DEGENERATE_BELOW, alt, t)
        t = t / torch.sqrt(_sum3(t * t))
        bt = self._cross(n_yzx, n_zxy, t)
        frames = torch.cat([t, bt, nrm], 1)  # (B, 9, V)
        view = _unit(eye.reshape(1, 3, 1) - pos)
        # pose features: first two columns of B_j^T R_j (rotation parts), non-root joints
        rl = local.index_select(1, self.feat_joints)[:, :, :3, :3]
        rl = rl / torch.sqrt((rl * rl).sum(2, keepdim=True))  # tiny (B, J', 3, 3)
        rel = self.bind_rel_t @ rl  # (B, J', 3, 3)
        feats = torch.cat([rel[..., :, 0], rel[..., :, 1]], -1).reshape(b, -1)
        return pos, nrm, frames, view, feats


def export_posing_graph(graph: PosingGraph, path: str | os.PathLike[str]) -> Path:
    """Export ``graph`` to ``path`` (batch axis ``B`` dynamic) with the project's :func:`export_onnx`."""
    from prt_torch.export.onnx_file import export_onnx

    ex = [torch.eye(4).expand(1, graph.n_joints, 4, 4).contiguous(), torch.zeros(3)]
    b = {0: "B"}
    return export_onnx(graph, ex, path, POSING_INPUTS, POSING_OUTPUTS, {"local": b, **{k: b for k in POSING_OUTPUTS}},
                       metadata={"graph": "posing", "n_vertices": graph.n_vertices})


def chain_posing_fused(posing_path: str | os.PathLike[str], fused_path: str | os.PathLike[str],
                       path: str | os.PathLike[str]) -> Path:
    """One ONNX file: the posing graph feeding the fused graph's ``pose``, ``frames``, ``view_dirs`` (inputs
    ``local``, ``eye`` + the fused graph's lighting/material inputs; output ``radiance``). The two graphs must work
    in the same vertex order."""
    import onnx
    from onnx import compose

    from prt_torch.io import atomic_path

    a, b = onnx.load(str(posing_path)), onnx.load(str(fused_path))
    ver = max(a.ir_version, b.ir_version)
    a.ir_version = b.ir_version = ver
    a = compose.add_prefix(a, "posing/")
    merged = compose.merge_models(a, b, io_map=[("posing/features", "pose"), ("posing/frames", "frames"),
                                                ("posing/view_dirs", "view_dirs")],
                                  outputs=["radiance"])
    path = Path(path)
    with atomic_path(path) as tmp:
        onnx.save(merged, str(tmp))
    return path

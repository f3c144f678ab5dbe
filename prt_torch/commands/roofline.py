"""The roofline model of ``prt bench play`` (skinned and deformable runs alike): the machine's copy bandwidth and
GEMM rate measured in the same run, the bytes and FLOPs each player step must move and run, and the bound.
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np


# -- the machine ------------------------------------------------------------------------------------
def copy_bandwidth(n_bytes: int = 1 << 28, repeats: int = 5) -> float:
    """Best-of-``repeats`` memory traffic in bytes/s of ``numpy.copyto`` between two ``n_bytes`` float32 buffers
    (read + write: ``2 n_bytes`` per copy, STREAM's accounting)."""
    a = np.ones(max(n_bytes, 1 << 16) // 4, dtype=np.float32)
    b = np.empty_like(a)
    np.copyto(b, a)
    best = float("inf")
    for _ in range(repeats):
        t0 = time.perf_counter()
        np.copyto(b, a)
        best = min(best, time.perf_counter() - t0)
    return 2.0 * a.nbytes / best


def gemm_rate(n_vertices: int, n_coeffs: int, n_terms: int, threads: int, repeats: int = 25) -> float:
    """Best FLOP/s of numpy's float32 GEMM of the shading's RPO step ``(C, k*C) @ (k*C, V)`` over
    ``repeats`` calls with 1 and with ``threads`` BLAS threads (2 threads lose badly whenever the other
    core is busy, so the better of the two is the machine's usable compute rate for that step)."""
    from threadpoolctl import threadpool_limits

    rng = np.random.default_rng(0)
    a = rng.standard_normal((n_coeffs, n_terms * n_coeffs)).astype(np.float32)
    x = rng.standard_normal((n_terms * n_coeffs, n_vertices)).astype(np.float32)
    out = np.empty((n_coeffs, n_vertices), np.float32)
    best = float("inf")
    for n in sorted({1, max(1, threads)}):
        with threadpool_limits(limits=n, user_api="blas"):
            for _ in range(3):
                np.matmul(a, x, out=out)
            for _ in range(repeats):
                t0 = time.perf_counter()
                np.matmul(a, x, out=out)
                best = min(best, time.perf_counter() - t0)
    return 2.0 * a.shape[0] * a.shape[1] * n_vertices / best


# -- the roofline model ------------------------------------------------------------------------------
def shading_flops(n_vertices: int, order: int, n_terms: int, n_lobes: int) -> float:
    """FLOPs of RPO shading per frame: per vertex ``k C^2`` MACs for ``sum_b a_b M_b v`` (dense RPO), ``P C`` per
    lobe for the lobe SH (``P`` monomials of degree ``< order``), ``P k`` for the view factors and ``3 K C`` for the
    lighting dot products; elementwise work is not counted."""
    c = order * order
    p = order * (order + 1) * (order + 2) // 6
    return 2.0 * n_vertices * (n_terms * c * c + n_lobes * p * c + p * n_terms + 3 * n_lobes * c)


def step_costs(n_vertices: int, order: int, n_terms: int, n_lobes: int, n_joints: int, model_bytes: int,
               model_macs: int, crowd: int = 1) -> dict[str, dict[str, float]]:
    """Bytes that must move and FLOPs that must run per step for ``crowd`` characters (float32 data):

    * ``posing``: read dense skin weights ``(J, V)``, rest positions/normals, cluster labels (int64); write
      positions, normals, frames ``(9, V)``, view directions - per character; FLOPs: the ``12 x J`` blend GEMM;
    * ``visibility``: the model's weights once per call, the ``(V, C)`` output per character; ``2 * macs``;
    * ``shading``: read visibility, frames, view directions, write radiance per character; :func:`shading_flops`;
    * ``fused``: visibility + shading without the visibility round trip.
    """
    v, c, n = n_vertices, order * order, crowd
    pose_bytes = n * v * (4 * n_joints + 4 * 6 + 8 + 4 * 18)
    pose_flops = n * 2.0 * 12 * n_joints * v
    vis_out = n * v * c * 4
    shade_io = n * v * 4 * (9 + 3 + 3)
    sh_flops = n * shading_flops(v, order, n_terms, n_lobes)
    model_flops = n * 2.0 * model_macs
    return {"posing": {"bytes": pose_bytes, "flops": pose_flops},
            "visibility": {"bytes": model_bytes + vis_out, "flops": model_flops},
            "shading": {"bytes": vis_out + shade_io, "flops": sh_flops},
            "fused": {"bytes": model_bytes + shade_io, "flops": model_flops + sh_flops}}


def bound(cost: dict[str, float], bandwidth: float, gemm_flops: float) -> dict[str, Any]:
    """``{bound_ms, memory_ms, compute_ms, bound_by}``: the roofline lower bound of a step."""
    mem = cost["bytes"] / bandwidth
    comp = cost["flops"] / gemm_flops
    return {"bound_ms": max(mem, comp) * 1e3, "memory_ms": mem * 1e3, "compute_ms": comp * 1e3,
            "bound_by": "memory" if mem >= comp else "compute"}


def compiled_shading_flops(n_vertices: int, order: int, n_terms: int, n_lobes: int, gaunt_nnz: int,
                           sh_nnz: int) -> float:
    """FLOPs of the compiled pass's shading per frame (:mod:`prt_torch.player.frame_kernels`): per vertex the local
    view and lobe directions (9 MACs each), their monomials (``P`` each), the view factors on the monomials (``k P``),
    ``u_eff`` (``k C``), the RPO's product form (2 per Gaunt non-zero), per lobe the SH table (``sh_nnz``) and the
    band-weighted RGB dot products (``3 C`` MACs)."""
    c = order * order
    p = order * (order + 1) * (order + 2) // 6
    macs = 9 * (1 + n_lobes) + p * (1 + n_lobes) + n_terms * p + n_terms * c + 1.5 * gaunt_nnz \
        + n_lobes * (sh_nnz + 3 * c)
    return 2.0 * n_vertices * macs


def compiled_costs(n_vertices: int, order: int, n_terms: int, n_lobes: int, pose_bytes: int, pose_nnz: int,
                   model_bytes: int, model_macs: int, gaunt_nnz: int, sh_nnz: int,
                   crowd: int = 1) -> dict[str, dict[str, float]]:
    """Bytes and FLOPs of the compiled frame path's two steps for ``crowd`` characters:

    * ``posing_compiled``: read the sparse skin weights, rest mesh and labels (``pose_bytes``, once per call), write
      positions, normals, frames and view directions per character; FLOPs: the LBS blend (``12`` MACs per non-zero
      weight) and ~60 per vertex for normals, frames and view directions;
    * ``compiled``: the latent graph's and the decode's bytes once per call (``model_bytes``: bases, scales, mean),
      frames and view directions in and radiance out per character; FLOPs: ``2 * model_macs`` (latent + decode) and
      :func:`compiled_shading_flops` per character.
    """
    v, n = n_vertices, crowd
    return {"posing_compiled": {"bytes": pose_bytes + n * v * 4 * 18,
                                "flops": n * (2.0 * 12 * pose_nnz + 60.0 * v)},
            "compiled": {"bytes": model_bytes + n * v * 4 * (9 + 3 + 3),
                         "flops": n * (2.0 * model_macs
                                       + compiled_shading_flops(v, order, n_terms, n_lobes, gaunt_nnz, sh_nnz))}}

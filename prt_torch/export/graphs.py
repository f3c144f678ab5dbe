"""The torch modules that become the run-time ONNX graphs.

* :class:`ShadingGraph` - RPO shading under ZH lighting lobes (seed 003 eq. 11 with the lobes of
  sec. 5.5 rotated into each vertex frame), every BRDF and lighting tensor a graph *input* so that
  materials and lights swap at run time;
* :class:`VisibilityGraph` - pose features -> local-frame SH visibility (wraps a ``VisibilityModel``);
* :class:`FusedGraph` - both in one graph.

Shapes: ``B`` batch, ``V`` vertices, ``C = n*n`` SH coefficients of order ``n``, ``K`` lighting
lobes, ``k`` BRDF terms, ``A`` pose-feature width. A frame ``F`` has rows ``(t, b, n)`` in world
coordinates, so a world direction ``w`` has local coordinates ``F @ w`` (docs/DESIGN.md). The
graphs take frames and view directions **vertex-last** (``(B, 9, V)`` and ``(B, 3, V)``: the layout
the player's posing path produces and the fastest one for onnxruntime); visibility is ``(B, V, C)``
as the model gives it, radiance ``(B, V, 3)``.

Shading, per vertex, with local lighting ``l (C, 3)``, visibility ``v (C,)``, local view ``wo``::

    a_b  = w_b . y(wo)                         (k,)    view factor of BRDF term b
    zz   = sum_b a_b M_b v                     (C,)    = Mcat @ (a (x) v): an outer product, one GEMM
    L_c  = tint_c * (l_c . zz)                 (3,)    (= tint_c sum_b a_b (l_c . M_b v), eq. 11)

and the local lighting of ``K`` ZH lobes ``(s_K, g_K (n, 3))`` is ``l = sum_K g_K[band] * y(F s_K)``;
``L_c`` is computed as ``sum_{K, i} g_K[band i, c] zz_i y_i(F s_K)`` (one small GEMM).
SH are evaluated as polynomials: a monomial table of the direction (built degree by degree with row
gathers, :class:`SHPolynomial`) times a constant matrix (:func:`prt_torch.sh.polynomial.sh_polynomial`), one MatMul
in the graph instead of a long chain of small ops.
"""

from __future__ import annotations

import numpy as np
import torch
from torch import nn

from prt_torch.brdf.rpo import DEFAULT_TERMS
from prt_torch.sh.basis import band_of
from prt_torch.sh.polynomial import monomial_recursion

#: graph input names, in order
SHADING_INPUTS = ("visibility", "frames", "view_dirs", "lobe_dirs", "lobe_coeffs", "rpo_M", "rpo_w", "rpo_tint")
FUSED_INPUTS = ("pose",) + SHADING_INPUTS[1:]
VISIBILITY_INPUTS = ("pose",)


class SHPolynomial(nn.Module):
    """Real SH basis of directions stored *component-first*: ``(..., 3, N) -> (..., C, N)``.

    Evaluated as ``coeffs^T @ monomials`` with the monomials built degree by degree: every monomial of
    degree ``d >= 2`` is a monomial of degree ``d - 1`` times one component, so each degree is ONE
    row-gather of the previous degree times ONE row-gather of the components (2 Gathers + 1 Mul per
    degree, then one Concat and one MatMul: ~12 graph nodes at order 4 instead of ~60 - at ~5 us of
    onnxruntime overhead per node that is most of the cost of the small per-direction ops).
    ``exps`` lists the monomials in that (degree-major) order; ``coeffs_t (C, P)`` matches it.
    """

    def __init__(self, order: int) -> None:
        super().__init__()
        exps, parent, comp, coeffs_t = monomial_recursion(order)
        self.order = order
        degree = np.array([sum(e) for e in exps])
        self._steps: list[tuple[str, str]] = []
        for deg in range(2, order):
            rows = np.flatnonzero(degree == deg)
            prev_start = int(np.flatnonzero(degree == deg - 1)[0])
            self.register_buffer(f"parent_{deg}", torch.as_tensor(parent[rows] - prev_start, dtype=torch.long),
                                 persistent=False)
            self.register_buffer(f"comp_{deg}", torch.as_tensor(comp[rows], dtype=torch.long), persistent=False)
            self._steps.append((f"parent_{deg}", f"comp_{deg}"))
        self.exps = exps
        self.register_buffer("coeffs_t", torch.as_tensor(coeffs_t, dtype=torch.float32), persistent=False)

    def forward(self, d: torch.Tensor) -> torch.Tensor:
        return self.coeffs_t @ self.monomials(d)  # (C, P) @ (..., P, N)

    def monomials(self, d: torch.Tensor) -> torch.Tensor:
        """``(..., 3, N) -> (..., P, N)`` the monomials ``x^a y^b z^c`` of :attr:`exps` (degree-major)."""
        parts = [torch.ones_like(d[..., :1, :])]
        if self.order > 1:
            parts.append(d)
        prev = d
        for parent, comp in self._steps:
            prev = prev.index_select(-2, getattr(self, parent)) * d.index_select(-2, getattr(self, comp))
            parts.append(prev)
        return torch.cat(parts, dim=-2)


class ShadingGraph(nn.Module):
    """RPO shading of local-frame visibility under ZH lobes, seen from given view directions.

    Inputs (float32):
        visibility ``(B, V, C)`` local-frame SH visibility;
        frames ``(B, 9, V)`` vertex-last: entry ``3i + j`` is ``F[i, j]`` of the frame with rows
        ``(t, b, n)`` in world coordinates (``F.reshape(9)`` per vertex, stacked along the last axis);
        view_dirs ``(B, 3, V)`` vertex-last unit world directions from the vertex towards the eye;
        lobe_dirs ``(K, 3)`` unit world lobe axes; lobe_coeffs ``(K, n, 3)`` per band, RGB;
        rpo_M ``(k, C, C)``, rpo_w ``(k, C)``, rpo_tint ``(3,)`` - the RPO.

    Output: radiance ``(B, V, 3)`` (linear, RGB).

    Internally everything is laid out vertex-last (``(B, ..., V)``) so that each step is either a
    MatMul with a small constant-size matrix or an elementwise product of contiguous V-long rows.
    """

    #: the forms of the RPO step ``zz = sum_b a_b M_b v`` (measured side by side; the outer form is the faster):
    #: ``"outer"``: one GEMM ``Mcat (C, k*C) @ (a (x) v) (k*C, V)``; ``"per_term"``: ``Mstack (k*C, C) @ v`` then
    #: the ``a_b``-weighted sum over terms (same FLOPs, a second ``(k*C, V)`` pass)
    RPO_FORMS = ("outer", "per_term")

    def __init__(self, order: int, n_terms: int = DEFAULT_TERMS, rpo_form: str = "outer") -> None:
        super().__init__()
        if rpo_form not in self.RPO_FORMS:
            raise ValueError(f"unknown RPO form {rpo_form!r}: expected one of {self.RPO_FORMS}")
        self.rpo_form = rpo_form
        self.order = order
        self.max_terms = n_terms
        self.sh = SHPolynomial(order)
        self.register_buffer("band", torch.as_tensor(band_of(order)), persistent=False)

    def forward(self, visibility: torch.Tensor, frames: torch.Tensor, view_dirs: torch.Tensor,
                lobe_dirs: torch.Tensor, lobe_coeffs: torch.Tensor, rpo_M: torch.Tensor, rpo_w: torch.Tensor,
                rpo_tint: torch.Tensor) -> torch.Tensor:
        return self.shade_vertex_last(visibility.transpose(1, 2), frames, view_dirs, lobe_dirs, lobe_coeffs,
                                      rpo_M, rpo_w, rpo_tint)

    def shade_vertex_last(self, vis_t: torch.Tensor, frames: torch.Tensor, view_dirs: torch.Tensor,
                          lobe_dirs: torch.Tensor, lobe_coeffs: torch.Tensor, rpo_M: torch.Tensor,
                          rpo_w: torch.Tensor, rpo_tint: torch.Tensor) -> torch.Tensor:
        """As :meth:`forward` with the visibility given vertex-last, ``vis_t (B, C, V)``."""
        k, c, _ = rpo_M.shape
        n_lobes = lobe_dirs.shape[0]
        b, v = frames.shape[0], frames.shape[2]
        ft = frames  # (B, 9, V): ft[., 3i+j, v] = F_v[i, j]
        # local coordinates F @ s of the K lobe axes: one MatMul with kron(I3, s) (K*3, 9)
        eye3 = torch.eye(3, dtype=frames.dtype)
        # rows ordered (component i, lobe K) so that each component is one contiguous (K*V) block
        s_kron = (eye3.reshape(3, 1, 3, 1) * lobe_dirs.reshape(1, n_lobes, 1, 3)).reshape(3 * n_lobes, 9)
        s_loc = (s_kron @ ft).reshape(b, 3, n_lobes * v)  # (B, 3, K*V): [i, K*V + v] = (F_v s_K)_i
        view_t = view_dirs  # (B, 3, V)
        # (B, 3, V) local view direction F @ wo: [i] = sum_j F[i, j] wo_j (one Mul, one ReduceSum)
        wo = (ft.reshape(b, 3, 3, v) * view_t.unsqueeze(1)).sum(2)
        y_lobes = self.sh(s_loc).reshape(b, c, n_lobes, v)  # (B, C, K, V)
        a = (rpo_w @ self.sh.coeffs_t) @ self.sh.monomials(wo)  # (B, k, V): view factors w_b . y(wo)
        # zz = sum_b a_b M_b v = Mcat @ (a (x) v): one elementwise outer product, one GEMM
        if self.rpo_form == "per_term":
            t = (rpo_M.reshape(k * c, c) @ vis_t).reshape(b, k, c, v)  # (B, k, C, V): M_b v
            zz = (t * a.unsqueeze(2)).sum(1)  # (B, C, V)
        else:
            m_cat = rpo_M.permute(1, 0, 2).reshape(c, k * c)  # (C, k*C): [i, b*C + j] = M[b, i, j]
            u = (a.unsqueeze(2) * vis_t.unsqueeze(1)).reshape(b, k * c, v)  # (B, k*C, V): a_b v_j
            zz = m_cat @ u  # (B, C, V)
        g = lobe_coeffs.index_select(1, self.band)  # (K, C, 3)
        g_t = g.permute(2, 1, 0).reshape(3, c * n_lobes)  # (3, C*K)
        p = (y_lobes * zz.unsqueeze(2)).reshape(b, c * n_lobes, v)  # (B, C*K, V)
        out = g_t @ p  # (B, 3, V)
        return (out * rpo_tint.reshape(1, 3, 1)).transpose(1, 2)  # (B, V, 3)


#: weight precisions of the exported output bases (``prt export --precision``): float32, float16 (weights and the
#: GEMM in half precision: half the bytes where the execution provider has half-precision kernels - CUDA; the
#: CPU provider widens them back at load), int8 (per-output-column block scales, onnxruntime's MatMulNBits)
PRECISIONS = ("fp32", "fp16", "int8")


def int8_block_size(k: int) -> int:
    """The MatMulNBits block length (a power of two >= 16) for a ``k``-row basis: the one that stores the fewest
    bytes per output column, ``ceil(k / b) * (b + 4)`` (int8 entries plus one float32 scale per block)."""
    return min((16, 32, 64, 128), key=lambda b: (-(-k // b) * (b + 4), b))


def int8_quantize(w: np.ndarray, block: int | None = None) -> tuple[np.ndarray, np.ndarray, int]:
    """Symmetric int8 quantisation of a ``(K, N)`` basis with one scale per output column and ``block`` rows.

    Returns ``q (N, n_blocks, block)`` int8 (rows past ``K`` zero), ``scales (N, n_blocks)`` float32 and the block
    length; ``w ~= dequantised = q * scale`` with ``scale = max |w_block| / 127`` (1 for an all-zero block).
    """
    w = np.asarray(w, dtype=np.float32)
    k, n = w.shape
    block = int8_block_size(k) if block is None else int(block)
    nb = -(-k // block)
    wt = np.zeros((n, nb * block), np.float32)
    wt[:, :k] = w.T
    wt = wt.reshape(n, nb, block)
    amax = np.abs(wt).max(axis=2)
    scales = np.where(amax > 0, amax / 127.0, 1.0).astype(np.float32)
    q = np.clip(np.rint(wt / scales[..., None]), -127, 127).astype(np.int8)
    return q, scales, block


def int8_dequantize(q: np.ndarray, scales: np.ndarray, k: int) -> np.ndarray:
    """The ``(K, N)`` float32 basis that :func:`int8_quantize`'s ``(q, scales)`` stand for."""
    n, nb, block = q.shape
    return np.ascontiguousarray((q.astype(np.float32) * scales[..., None]).reshape(n, nb * block)[:, :k].T)


def int8_activations(z: torch.Tensor, block: int) -> torch.Tensor:
    """``z (..., K)`` rounded as onnxruntime's int8-compute MatMulNBits rounds its input (accuracy level 4):
    symmetric int8 per block of ``block`` entries along ``K``, scale ``max |z_block| / 127`` - the torch reference of
    the int8 graphs (parity), never exported."""
    k = z.shape[-1]
    nb = -(-k // block)
    pad = torch.nn.functional.pad(z, (0, nb * block - k)).reshape(*z.shape[:-1], nb, block)
    scale = pad.abs().amax(-1, keepdim=True) / 127.0
    q = torch.where(scale > 0, torch.round(pad / torch.where(scale > 0, scale, torch.ones_like(scale))), pad)
    return (q * scale).reshape(*z.shape[:-1], nb * block)[..., :k]


class CompactUnprojection(nn.Module):
    """The per-cluster output PCA of a ``VisibilityModel`` without its zero padding.

    ``OutputUnprojection`` stores one ``(G, Kmax, Lmax)`` basis padded to the largest cluster and the
    most components; at ~11.7k vertices most of those bytes are zeros, and the run-time cost of the
    model is streaming its bytes. Here each cluster ``g`` keeps only its used block ``(K_g, L_g)``
    (one MatMul per cluster, then Concat), and the gather indices are remapped into the compact
    layout - the same numbers, exactly (only zero rows/columns are dropped). With ``vertex_last`` the
    gather also transposes: the output is ``(B, C, V)`` at no extra cost.

    ``cluster_sorted`` (every vertex's ``C`` coefficients in one cluster): the output is ``(B, C, V)`` in
    CLUSTER-SORTED vertex order (:attr:`vertex_order`: position ``i`` holds vertex ``vertex_order[i]``; the
    clusters one after the other, each cluster's vertices ascending) - each cluster's basis columns are stored in
    (coefficient, vertex) order so its GEMM writes one contiguous ``(B, C, n_g)`` block and a Concat along the
    vertices ends it: no gather at all. Otherwise :attr:`vertex_order` is ``None`` (original order).

    ``precision`` (:data:`PRECISIONS`): ``"fp16"`` keeps the bases in float16 and runs their GEMMs in half
    precision (exported as Cast -> MatMul(float16) -> Cast); ``"int8"`` rounds them to int8 with per-column block
    scales (:func:`int8_quantize`) - the ONNX file gets onnxruntime's MatMulNBits for them
    (:func:`prt_torch.export.onnx_file.lower_int8_matmuls`); this module then multiplies with the dequantised
    values (and, with :attr:`emulate_int8` set, rounds its input as onnxruntime does: the parity reference). An int8
    module also rounds its mean through float16, as the int8 export stores it.
    """

    def __init__(self, out: nn.Module, vertex_last: bool = False, cluster_sorted: bool = False,
                 precision: str = "fp32") -> None:
        super().__init__()
        if precision not in PRECISIONS:
            raise ValueError(f"unknown precision {precision!r}: expected one of {PRECISIONS}")
        self.precision = precision
        self.emulate_int8 = False
        self.vertex_order: np.ndarray | None = None
        self.int8_blocks: list[int] = []
        basis = out.basis.detach().float()
        gather = out.gather.detach().long()
        g_count, _, l_max = basis.shape
        self.n_groups = g_count
        self.n_vertices = v = int(out.n_vertices)
        self.n_coeffs = c = int(out.n_coeffs)
        grp, col = gather // l_max, gather % l_max
        grp_vc = grp.reshape(v, c)
        # row mode: every vertex's C coefficients come from one cluster -> reorder each cluster's
        # columns to (vertex, coefficient) so that the unprojection ends in a gather of whole
        # (C,)-rows (V indices) instead of V*C single floats
        one_cluster = bool((grp_vc == grp_vc[:, :1]).all())
        self.cluster_sorted = cluster_sorted and one_cluster
        self.row_mode = one_cluster and not vertex_last and not self.cluster_sorted
        self.vertex_last = vertex_last or self.cluster_sorted
        self.k_used: list[int] = []
        self.n_used: list[int] = []
        mean = out.mean.detach().float()
        if precision == "int8":  # stored in float16 by the int8 lowering (prt_torch.export.run.MEAN_PATTERN)
            mean = mean.half().float()
        if self.cluster_sorted:
            vgrp = grp_vc[:, 0]
            col_vc = col.reshape(v, c)
            order_s: list[torch.Tensor] = []
            for g in range(g_count):
                verts = torch.nonzero(vgrp == g).flatten()  # ascending
                cols = col_vc[verts].t().reshape(-1)  # (C * n_g,) in (coefficient, vertex) order
                blk = basis[g][:, cols] if cols.numel() else basis[g][:, :0]
                rows = torch.nonzero(blk.abs().sum(dim=1) > 0).flatten()
                k_g = int(rows.max()) + 1 if rows.numel() else 0
                self.register_buffer(f"basis_{g}", self._stored(blk[:k_g].contiguous()))
                self.k_used.append(k_g)
                self.n_used.append(int(verts.numel()))
                order_s.append(verts)
            perm = torch.cat(order_s)
            self.vertex_order = perm.numpy().astype(np.int64)
            self.register_buffer("mean", mean.reshape(v, c)[perm].t().contiguous().reshape(1, c, v))
            return
        if self.row_mode:
            vgrp = grp_vc[:, 0]
            col_vc = col.reshape(v, c)
            order: list[torch.Tensor] = []
            for g in range(g_count):
                verts = torch.nonzero(vgrp == g).flatten()  # ascending
                cols = col_vc[verts].reshape(-1)  # (n_g * C,) in (vertex, c) order
                blk = basis[g][:, cols] if cols.numel() else basis[g][:, :0]
                rows = torch.nonzero(blk.abs().sum(dim=1) > 0).flatten()
                k_g = int(rows.max()) + 1 if rows.numel() else 0
                self.register_buffer(f"basis_{g}", self._stored(blk[:k_g].contiguous()))
                self.k_used.append(k_g)
                order.append(verts)
            perm = torch.cat(order)  # sorted position -> vertex
            inv = torch.empty(v, dtype=torch.long)
            inv[perm] = torch.arange(v)
            self.register_buffer("gather", inv.to(torch.int32))  # vertex -> sorted position
            self.register_buffer("mean", mean.reshape(v, c))
            return
        offsets = torch.zeros(g_count, dtype=torch.long)
        start = 0
        for g in range(g_count):
            cols = col[grp == g]
            l_g = int(cols.max()) + 1 if cols.numel() else 0
            rows = torch.nonzero(basis[g, :, :l_g].abs().sum(dim=1) > 0).flatten()
            k_g = int(rows.max()) + 1 if rows.numel() else 0
            self.register_buffer(f"basis_{g}", self._stored(basis[g, :k_g, :l_g].contiguous()))
            self.k_used.append(k_g)
            offsets[g] = start
            start += l_g
        gather_c = (offsets[grp] + col).to(torch.int32)
        if vertex_last:  # permute the gather so that the output comes out as (B, C, V)
            gather_c = gather_c.reshape(v, c).t().contiguous().reshape(-1)
            mean = mean.reshape(v, c).t().contiguous().reshape(-1)
        self.register_buffer("gather", gather_c)
        self.register_buffer("mean", mean)

    def _stored(self, blk: torch.Tensor) -> torch.Tensor:
        """A ``(K_g, L_g)`` basis block as stored for :attr:`precision`."""
        if self.precision == "fp16":
            return blk.half()
        if self.precision == "int8" and blk.numel():
            q, scales, block = int8_quantize(blk.numpy())
            self.int8_blocks.append(block)
            return torch.from_numpy(int8_dequantize(q, scales, blk.shape[0]))
        self.int8_blocks.append(0)
        return blk

    def _inputs(self, z: torch.Tensor) -> list[torch.Tensor]:
        """``z (B, G, K)`` -> each cluster's used inputs ``(B, K_g)``: one Split node when every cluster uses all
        ``K`` (a Slice + Squeeze pair per cluster otherwise: ~0.3 ms of node overhead at 32 clusters)."""
        k = int(z.shape[2])
        if all(k_g == k for k_g in self.k_used):
            return list(torch.split(z.flatten(1), k, dim=1))
        return [z[:, g, : self.k_used[g]] for g in range(self.n_groups)]

    def _cluster(self, zg: torch.Tensor, g: int) -> torch.Tensor:
        """Cluster ``g``'s inputs ``zg (B, K_g)`` -> its output ``(B, L_g)`` at the stored precision."""
        w = getattr(self, f"basis_{g}")
        if self.precision == "fp16":
            return (zg.half() @ w).float()
        if self.precision == "int8" and self.emulate_int8:
            zg = int8_activations(zg, self.int8_blocks[g])
        return zg @ w

    def forward(self, z: torch.Tensor) -> torch.Tensor:
        b = z.shape[0]
        if self.cluster_sorted:  # (B, C, n_g) blocks, concatenated along the (cluster-sorted) vertices
            zs = self._inputs(z)
            blocks = [self._cluster(zs[g], g).reshape(b, self.n_coeffs, self.n_used[g])
                      if getattr(self, f"basis_{g}").numel() else z.new_zeros(b, self.n_coeffs, self.n_used[g])
                      for g in range(self.n_groups) if self.n_used[g]]
            return torch.cat(blocks, dim=2) + self.mean
        zs = self._inputs(z)
        parts = [self._cluster(zs[g], g) for g in range(self.n_groups) if getattr(self, f"basis_{g}").numel()]
        y = torch.cat(parts, dim=1)  # (B, sum L_g)
        if self.row_mode:
            return y.reshape(b, self.n_vertices, self.n_coeffs).index_select(1, self.gather) + self.mean
        out = y.index_select(1, self.gather) + self.mean
        if self.vertex_last:
            return out.reshape(b, self.n_coeffs, self.n_vertices)
        return out.reshape(b, self.n_vertices, self.n_coeffs)


class QuantizedInputProjection(nn.Module):
    """An :class:`~prt_torch.models.projection.InputProjection` ``(x - mean) @ proj`` with ``proj (A, d)`` rounded to
    int8 (:func:`int8_quantize`, blocks along ``A``): the int8 export's input end. Its weight is the buffer
    ``basis_0`` so that the int8 lowering (``prt_torch.export.run.BASIS_PATTERN``) makes it a MatMulNBits; the
    module multiplies with the dequantised values (and, with :attr:`emulate_int8`, rounds ``x - mean`` as
    onnxruntime does). For a deformable run ``A`` is every interior edge of the cloth (~22k at 7.7k vertices): in
    float32 this projection alone is 4 A d bytes, more than the whole int8 output basis."""

    def __init__(self, inp: nn.Module) -> None:
        super().__init__()
        proj = inp.proj.detach().float().numpy()
        q, scales, self.block = int8_quantize(proj)
        self.register_buffer("mean", inp.mean.detach().float().clone())
        self.register_buffer("basis_0", torch.from_numpy(int8_dequantize(q, scales, proj.shape[0])))
        self.emulate_int8 = False

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        xc = x - self.mean
        if self.emulate_int8:
            xc = int8_activations(xc, self.block)
        return xc @ self.basis_0


class VisibilityGraph(nn.Module):
    """``pose (B, A) -> visibility (B, V, C)``.

    A ``VisibilityModel`` (``inp``, ``regressor``, ``out`` submodules) is exported with its output
    unprojection compacted (:class:`CompactUnprojection`); any other module is used as is.
    """

    def __init__(self, model: nn.Module, compact: bool = True, vertex_last: bool = False,
                 cluster_sorted: bool = False, precision: str = "fp32") -> None:
        super().__init__()
        self.model = model
        from prt_torch.models.projection import OutputUnprojection

        self.compact = compact and all(hasattr(model, a) for a in ("inp", "regressor", "out")) \
            and isinstance(model.out, OutputUnprojection)  # the per-cluster (padded) layout only
        if precision != "fp32" and not self.compact:
            raise ValueError(f"precision {precision!r} needs a per-cluster VisibilityModel (this is "
                             f"{type(model).__name__})")
        self.vertex_last = vertex_last
        #: cluster-sorted export order of the output's vertex axis (``None``: original order)
        self.vertex_order: np.ndarray | None = None
        self.precision = precision
        if self.compact:
            self.out = CompactUnprojection(model.out, vertex_last=vertex_last, cluster_sorted=cluster_sorted,
                                           precision=precision)
            self.vertex_last = self.out.vertex_last
            self.vertex_order = self.out.vertex_order
            from prt_torch.models.projection import InputProjection

            self.inp: nn.Module = QuantizedInputProjection(model.inp) \
                if precision == "int8" and isinstance(model.inp, InputProjection) else model.inp

    def emulate_int8(self, on: bool = True) -> None:
        """Round the int8 GEMMs' inputs as onnxruntime does (the parity reference of an int8 export)."""
        if self.compact:
            self.out.emulate_int8 = on
            if isinstance(self.inp, QuantizedInputProjection):
                self.inp.emulate_int8 = on

    def forward(self, pose: torch.Tensor) -> torch.Tensor:
        """``(B, A) -> (B, V, C)``, or ``(B, C, V)`` when built with ``vertex_last``."""
        if self.compact:
            return self.out(self.model.regressor(self.inp(pose)))
        v = self.model(pose)
        return v.transpose(1, 2) if self.vertex_last else v


def set_int8_emulation(module: nn.Module, on: bool) -> None:
    """Switch the int8 input rounding of every :class:`VisibilityGraph` in ``module`` (the parity reference)."""
    for m in module.modules():
        if isinstance(m, VisibilityGraph):
            m.emulate_int8(on)


class FusedGraph(nn.Module):
    """Pose features straight to radiance: :class:`VisibilityGraph` then :class:`ShadingGraph`."""

    def __init__(self, model: nn.Module, order: int, n_terms: int = DEFAULT_TERMS, vertex_last: bool = False,
                 cluster_sorted: bool = False, precision: str = "fp32") -> None:
        super().__init__()
        if isinstance(model, VisibilityGraph):
            model = model.model
        self.model = VisibilityGraph(model, vertex_last=vertex_last, cluster_sorted=cluster_sorted,
                                     precision=precision)
        self.vertex_last = self.model.vertex_last
        #: export order of every vertex axis (frames, view_dirs in; radiance out); ``None``: original order
        self.vertex_order = self.model.vertex_order
        self.shading = ShadingGraph(order, n_terms)

    def forward(self, pose: torch.Tensor, frames: torch.Tensor, view_dirs: torch.Tensor, lobe_dirs: torch.Tensor,
                lobe_coeffs: torch.Tensor, rpo_M: torch.Tensor, rpo_w: torch.Tensor,
                rpo_tint: torch.Tensor) -> torch.Tensor:
        vis = self.model(pose)
        if not self.vertex_last:  # (B, V, C): the transpose fuses into the RPO MatMul (transB)
            vis = vis.transpose(1, 2)
        return self.shading.shade_vertex_last(vis, frames, view_dirs, lobe_dirs, lobe_coeffs, rpo_M, rpo_w, rpo_tint)


class FusedPeaksGraph(nn.Module):
    """``fused_peaks.onnx`` (:mod:`prt_torch.export.peaks_graph`): ``fused`` (a :class:`FusedGraph`) plus the peak
    lights' term with the learned ``blockers`` (a :class:`~prt_torch.models.peak_blockers.PeakBlockers`): the
    whole radiance ``(B, V, 3)`` and the peaks' visibility ``(B, V, P)``."""

    def __init__(self, fused: nn.Module, blockers: nn.Module) -> None:
        super().__init__()
        self.fused = fused
        self.blockers = blockers

    def forward(self, pose: torch.Tensor, frames: torch.Tensor, view_dirs: torch.Tensor, lobe_dirs: torch.Tensor,
                lobe_coeffs: torch.Tensor, rpo_M: torch.Tensor, rpo_w: torch.Tensor, rpo_tint: torch.Tensor,
                positions: torch.Tensor, skin: torch.Tensor, peak_directions: torch.Tensor, peak_radii: torch.Tensor,
                peak_powers: torch.Tensor, peak_brdf: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        from prt_torch.brdf.direct_graph import peak_radiance_graph

        residual = self.fused(pose, frames, view_dirs, lobe_dirs, lobe_coeffs, rpo_M, rpo_w, rpo_tint)
        vis = self.blockers(positions.transpose(1, 2), frames[:, 6:9].transpose(1, 2), skin, peak_directions,
                            peak_radii)
        return residual + peak_radiance_graph(frames, view_dirs, peak_directions, peak_powers, vis, peak_brdf), vis

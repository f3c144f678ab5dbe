"""Fitting per-cluster tanh networks (seed 003 eqs. 12-13) with one L-BFGS over a whole batch.

The batch axes are ``S`` settings (cross-validation fold x alpha, or the single final fit) and
``G`` clusters. Objective, summed over the batch (the terms are independent, so the joint
minimiser is every term's minimiser)::

    sum_{s,g} [ sum_i w_si ||Z~_g(X_i) - Z_ig||^2 + alpha_sg (||C_sg||^2 + ||D_sg||^2) ]

with ``w_si`` 0/1 sample weights (the fold's training frames) and padded output dimensions and
unused neurons masked out. Fit in float64 (``torch.optim.LBFGS`` with strong-Wolfe line search;
float32 L-BFGS stalls, pytorch#49993); the output layer is initialised by ridge on the random
hidden layer's activations.

The objective and its gradient are analytic (:class:`MLPObjective`), not autograd: every evaluation
writes into buffers allocated once per fit (``bmm(..., out=)``, in-place element-wise ops), since
re-allocating the ``(S, G, F, K)`` residual at every step cost more kernel time (page faults) than the
arithmetic. Clusters with similar input/output counts share padded blocks and a CV fold's settings skip
its held-out frames, which removes most of the padding arithmetic; the result is the same objective
(:func:`reference_objective`, tested against autograd) and the same ``torch.optim.LBFGS`` settings.

Device: the fit runs where its input tensors are (or on ``device``): the data is moved there once per fit,
the parameters, L-BFGS state and every work buffer live there, and :func:`fit_mlp` returns the parameters
on the CPU. On the CPU the tanh runs in numpy (SIMD, into the same memory); elsewhere in torch, and the
per-block objective terms are summed on the device (one host sync per evaluation instead of one per block).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import torch

from prt_torch.errors import check
from prt_torch.shapes import check_shape

DT = torch.float64


@dataclass
class MLPParams:
    """Batched parameters: ``D (S, G, N, d)``, ``d0 (S, G, N)``, ``C (S, G, K, N)``, ``c0 (S, G, K)``."""

    D: torch.Tensor
    d0: torch.Tensor
    C: torch.Tensor
    c0: torch.Tensor

    def to(self, device: torch.device | str) -> MLPParams:
        """The parameters on ``device`` (the same tensors where they are there already)."""
        return MLPParams(*(t.to(device) for t in (self.D, self.d0, self.C, self.c0)))


def mlp_forward(x: torch.Tensor, p: MLPParams) -> torch.Tensor:
    """``x (F, d)`` -> ``(S, G, F, K)``."""
    h = torch.tanh(torch.einsum("fd,sgnd->sgfn", x, p.D) + p.d0.unsqueeze(2))
    return torch.einsum("sgfn,sgkn->sgfk", h, p.C) + p.c0.unsqueeze(2)


def reference_objective(x: torch.Tensor, z: torch.Tensor, out_mask: torch.Tensor, sample_weight: torch.Tensor,
                        alpha: torch.Tensor, p: MLPParams) -> torch.Tensor:
    """Eq. 13 summed over the batch, written plainly (autograd-able; the reference for :class:`MLPObjective`).

    ``x (F, d)``, ``z (F, G, K)``, ``out_mask (G, K)``, ``sample_weight (S, F)``, ``alpha (S, G)``, ``p``
    already masked -> scalar ``sum_{s,g,i} w_si ||(Z~_sg(x_i) - z_ig) * out_mask_g||^2 + alpha_sg (||C||^2 + ||D||^2)``.
    """
    om = out_mask.to(p.D.dtype)
    r = (mlp_forward(x.to(p.D.dtype), p) - z.to(p.D.dtype).permute(1, 0, 2).unsqueeze(0)) * om[None, :, None, :]
    data = (r.pow(2).sum(-1) * sample_weight.to(p.D.dtype)[:, None, :]).sum()
    return data + (alpha.to(p.D.dtype) * (p.C.pow(2).sum((2, 3)) + p.D.pow(2).sum((2, 3)))).sum()


class _Block:
    """Clusters ``idx (Gb,)`` x settings ``sidx (Sb,)`` on frames ``frames (Fb,)`` (those the settings weigh),
    in one padded layout: ``e`` inputs, ``k`` outputs (see :class:`MLPObjective`)."""

    def __init__(self, idx: torch.Tensor, sidx: torch.Tensor, frames: torch.Tensor, e: int, k: int, x: torch.Tensor,
                 z: torch.Tensor, om: torch.Tensor, cols: list[torch.Tensor], nm: torch.Tensor, w: torch.Tensor,
                 alpha: torch.Tensor, offset: int) -> None:
        """``idx``, ``sidx``, ``frames``, ``cols`` index tensors on the CPU; the data on the fit's device."""
        dev = x.device
        gb, s, n, f = len(idx), len(sidx), nm.shape[2], len(frames)
        cpu_idx, idx, sidx, frames = idx, idx.to(dev), sidx.to(dev), frames.to(dev)
        x, z = x[frames], z[frames]
        self.idx, self.sidx, self.e, self.k, self.shape, self.offset = idx, sidx, e, k, (gb, s, n, f), offset
        gather = torch.zeros(gb, e, dtype=torch.int64)  # (Gb, e) input index (padding: 0, masked)
        valid = torch.zeros(gb, e, dtype=DT)
        for i, g in enumerate(cpu_idx.tolist()):
            gather[i, :len(cols[g])] = cols[g]
            valid[i, :len(cols[g])] = 1.0
        self.gather, self.valid = gather.to(dev), valid.to(dev)
        self.xt = torch.ones(gb, f, e + 1, dtype=DT, device=dev)  # (Gb, F, e + 1): gathered inputs, a ones column last
        self.xt[:, :, :e] = x[:, self.gather].permute(1, 0, 2) * self.valid[:, None, :]
        omb = om[idx, :k]  # (Gb, k)
        zb = z[:, idx, :k].permute(1, 2, 0)  # (Gb, k, F)
        self.zt = torch.where(omb[:, :, None] != 0, zb, 0.0).unsqueeze(1).contiguous()  # (Gb, 1, k, F), pad zeroed
        self.w2 = (2.0 * w[sidx][:, frames])[None, :, None, :].contiguous()  # (1, Sb, 1, Fb)
        self.alpha = alpha[sidx][:, idx].T.contiguous()  # (Gb, Sb)
        self.alpha2 = (2.0 * self.alpha)[:, :, None, None]  # (Gb, S, 1, 1)
        self.n_d = gb * s * n * (e + 1)
        self.size = self.n_d + gb * s * k * (n + 1)
        nmb = nm[sidx][:, idx].transpose(0, 1)  # (Gb, Sb, N)
        self.mask = torch.empty(self.size, dtype=DT, device=dev)
        md, mc = self._split(self.mask)
        md[..., :e] = nmb[..., None] * self.valid[:, None, None, :]
        md[..., e] = nmb
        mc[..., :n] = omb[:, None, :, None] * nmb[:, :, None, :]
        mc[..., n] = omb[:, None, :]
        # work buffers, reused by every evaluation
        self.pre = torch.empty(gb, s * n, f, dtype=DT, device=dev)  # hidden pre-activation, then dL/d(pre)
        self.ht = torch.ones(gb * s, n + 1, f, dtype=DT, device=dev)  # tanh activations, a ones row last
        self.r = torch.empty(gb * s, k, f, dtype=DT, device=dev)  # residual
        self.ew = torch.empty(gb * s, k, f, dtype=DT, device=dev)  # 2 w * residual = dL/dZ
        self.sq_c = torch.empty(gb, s, k, n, dtype=DT, device=dev)
        self.sq_d = torch.empty(gb, s, n, e, dtype=DT, device=dev)
        self.sum_c = torch.empty(gb, s, dtype=DT, device=dev)
        self.sum_d = torch.empty(gb, s, dtype=DT, device=dev)
        # on the CPU, numpy views of the same memory: numpy's float64 tanh is SIMD (about 4x torch's here)
        self.on_cpu = dev.type == "cpu"
        self.pre_np = self.pre.view(gb * s, n, f).numpy() if self.on_cpu else None
        self.h_np = self.ht[:, :n, :].numpy() if self.on_cpu else None

    def _split(self, part: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """This block's ``(size,)`` -> ``Dt (Gb, S, N, e + 1)``, ``Ct (Gb, S, k, N + 1)`` (views)."""
        gb, s, n, _ = self.shape
        return part[:self.n_d].view(gb, s, n, self.e + 1), part[self.n_d:].view(gb, s, self.k, n + 1)

    def views(self, flat: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """This block's slice of the whole flat ``(P,)`` as ``Dt``, ``Ct`` (views)."""
        return self._split(flat[self.offset:self.offset + self.size])

    def __call__(self, theta: torch.Tensor, grad: torch.Tensor | None) -> float | torch.Tensor:
        """Eq. 13 of this block's clusters (a float on the CPU, a 0-d tensor on another device); with ``grad``
        its gradient written into the block's slice."""
        gb, s, n, f = self.shape
        e, k = self.e, self.k
        dt, ct = self.views(theta)
        h = self.ht[:, :n, :]  # (Gb*S, N, F) view
        torch.bmm(dt.view(gb, s * n, e + 1), self.xt.transpose(1, 2), out=self.pre)
        if self.on_cpu:
            np.tanh(self.pre_np, out=self.h_np)  # h = tanh(pre), into the activation buffer
        else:
            torch.tanh(self.pre.view(gb * s, n, f), out=h)
        torch.bmm(ct.view(gb * s, k, n + 1), self.ht, out=self.r)
        r4 = self.r.view(gb, s, k, f)
        r4.sub_(self.zt)
        torch.mul(r4, self.w2, out=self.ew.view(gb, s, k, f))
        data_t = torch.dot(self.ew.view(-1), self.r.view(-1))
        c, dw = ct[..., :n], dt[..., :e]
        torch.mul(c, c, out=self.sq_c)
        torch.mul(dw, dw, out=self.sq_d)
        torch.sum(self.sq_c, dim=(2, 3), out=self.sum_c)
        torch.sum(self.sq_d, dim=(2, 3), out=self.sum_d)
        self.sum_c.add_(self.sum_d)
        pen_t = torch.dot(self.alpha.view(-1), self.sum_c.view(-1))
        if self.on_cpu:
            data, pen = 0.5 * float(data_t), float(pen_t)
        else:  # stays on the device: no sync per block
            data, pen = 0.5 * data_t, pen_t
        if grad is None:
            return data + pen
        gd, gc = self.views(grad)
        torch.bmm(self.ew, self.ht.transpose(1, 2), out=gc.view(gb * s, k, n + 1))
        gc[..., :n].addcmul_(c, self.alpha2)
        dh = self.pre.view(gb * s, n, f)
        torch.bmm(ct.view(gb * s, k, n + 1)[:, :, :n].transpose(1, 2), self.ew, out=dh)
        torch.ops.aten.tanh_backward.grad_input(dh, h, grad_input=dh)
        torch.bmm(self.pre, self.xt, out=gd.view(gb, s * n, e + 1))
        gd[..., :e].addcmul_(dw, self.alpha2)
        return data + pen


def _blocks_of(cost: list[tuple[int, int]], per_cluster: float, per_block: float) -> list[list[int]]:
    """Group clusters into padded blocks: ``cost[g] = (e_g, k_g)``; a block pads to its largest ``e``, ``k``.

    Clusters sorted by ``2 (e + 1) + 3 (k + 1)`` (the flops per frame and neuron of one evaluation) are cut
    into contiguous runs minimising ``sum_b |b| per_cluster (2 (e_b + 1) + 3 (k_b + 1)) + per_block`` (DP).
    """
    order = sorted(range(len(cost)), key=lambda g: (2 * cost[g][0] + 3 * cost[g][1], cost[g]))
    m = len(order)
    best = [0.0] + [float("inf")] * m
    cut = [0] * (m + 1)
    for j in range(1, m + 1):
        e = k = 0
        for i in range(j - 1, -1, -1):  # the block order[i:j]
            e, k = max(e, cost[order[i]][0]), max(k, cost[order[i]][1])
            c = best[i] + (j - i) * per_cluster * (2 * (e + 1) + 3 * (k + 1)) + per_block
            if c < best[j]:
                best[j], cut[j] = c, i
    blocks, j = [], m
    while j > 0:
        blocks.append(order[cut[j]:j])
        j = cut[j]
    return blocks[::-1]


class MLPObjective:
    """Eq. 13 and its analytic gradient over the whole batch, evaluated without allocating.

    The parameters live in one flat float64 vector ``theta`` (what L-BFGS moves). Clusters are grouped
    into blocks of similar size (:func:`_blocks_of`); a block of ``Gb`` clusters holds, cluster-major::

        Dt (Gb, S, N, e + 1)   hidden weights on the cluster's own inputs, the hidden bias last
        Ct (Gb, S, k, N + 1)   output weights, the output bias last

    with ``e`` the most inputs (``input_mask``) and ``k`` the most real outputs (``out_mask``) of a
    cluster in the block: the hidden layer multiplies the gathered inputs ``Xt (Gb, F, e + 1)`` (a ones
    column last) instead of all ``d``, and padded outputs beyond ``k`` are not computed. Forward and
    backward are a handful of ``bmm`` and in-place element-wise ops per block into buffers allocated once
    here (``(Gb*S, N+1, F)``, ``(Gb*S, k, F)`` x 2, ``(Gb, S*N, F)``). Masked coordinates (unused neurons,
    padded outputs, unselected inputs) have zero value and zero gradient, so L-BFGS never moves them, as
    with the reference's ``params * mask``. Masks must be 0/1.
    """

    def __init__(self, x: torch.Tensor, z: torch.Tensor, out_mask: torch.Tensor, sample_weight: torch.Tensor,
                 alpha: torch.Tensor, neuron_mask: torch.Tensor, input_mask: torch.Tensor | None = None,
                 max_blocks: int = 24, block_cost: float = 3e6, max_groups: int = 8) -> None:
        """``x (F, d)``, ``z (F, G, K)``, ``out_mask (G, K)``, ``sample_weight (S, F)``, ``alpha (S, G)``,
        ``neuron_mask (S, G, N)``, ``input_mask (G, d)`` (None: every input); at most ``max_blocks`` (>= 1)
        blocks, each costing ``block_cost`` flops more (its ~15 op launches, ~10 us each) than its padded work;
        settings are grouped by equal sample weights when there are at most ``max_groups`` distinct rows."""
        f, d = x.shape
        s, g, n = neuron_mask.shape
        k = z.shape[2]
        dev = x.device
        check(z.shape[:2] == (f, g) and out_mask.shape == (g, k),
              f"mlp fit: targets {tuple(z.shape)} / out_mask {tuple(out_mask.shape)} do not match inputs ({f}) / "
              f"clusters ({g})")
        check(sample_weight.shape == (s, f) and alpha.shape == (s, g), "mlp fit: bad sample_weight/alpha shapes")
        im = torch.ones(g, d, dtype=DT, device=dev) if input_mask is None else input_mask.to(dev, DT)
        check_shape(im, (g, d), name="mlp fit: input_mask")
        om = out_mask.to(dev, DT)
        for name, m in (("neuron_mask", neuron_mask), ("out_mask", om), ("input_mask", im)):
            check(bool(((m == 0) | (m == 1)).all()), f"mlp fit: {name} must be 0/1")
        self.shape = (s, g, n, d, k)
        # the block layout is planned on the CPU (small index tensors); the data stays on the device
        im_h, om_h = im.cpu(), om.cpu()
        cols = [torch.nonzero(im_h[i] != 0).flatten() for i in range(g)]
        # real outputs: up to the last unmasked one (a masked one before it stays masked in the block)
        kg = [int(torch.nonzero(om_h[i] != 0).max()) + 1 if bool((om_h[i] != 0).any()) else 0 for i in range(g)]
        x, z, w = x.to(DT), z.to(dev, DT), sample_weight.to(dev, DT)
        a, nm = alpha.to(dev, DT), neuron_mask.to(dev, DT)
        # settings with the same sample weights (a CV fold's alphas) share the frames they weigh: zero-weight
        # frames (the held-out fold) are left out of the products (exact: they add zeros)
        rows, inv = torch.unique(w.cpu(), dim=0, return_inverse=True)
        if len(rows) > max_groups:
            settings = [(torch.arange(s), torch.arange(f))]
        else:
            settings = [(torch.nonzero(inv == i).flatten(), torch.nonzero(row != 0).flatten())
                        for i, row in enumerate(rows)]
        self.blocks: list[_Block] = []
        offset = 0
        for sidx, frames in settings:
            per_block = block_cost / (2.0 * len(sidx) * max(len(frames), 1) * max(n, 1))  # in cluster-dims
            groups = _blocks_of([(len(c), kk) for c, kk in zip(cols, kg, strict=True)], 1.0, per_block)
            while len(groups) > max(1, max_blocks // len(settings)):  # merge the smallest adjacent pair
                i = min(range(len(groups) - 1), key=lambda j: len(groups[j]) + len(groups[j + 1]))
                groups[i:i + 2] = [groups[i] + groups[i + 1]]
            for grp in groups:
                idx = torch.as_tensor(sorted(grp), dtype=torch.int64)
                blk = _Block(idx, sidx, frames, max(len(cols[i]) for i in grp), max(kg[i] for i in grp), x, z, om,
                             cols, nm, w, a, offset)
                self.blocks.append(blk)
                offset += blk.size
        self.size = offset
        self.mask = torch.cat([b.mask for b in self.blocks])

    def pack(self, p: MLPParams) -> torch.Tensor:
        """Batched parameters (masked, on the objective's device) -> a new flat ``theta (P,)`` there."""
        theta = torch.empty(self.size, dtype=DT, device=self.mask.device)
        for b in self.blocks:
            gb, s, n, _ = b.shape
            dt, ct = b.views(theta)
            def sel(t: torch.Tensor, b: _Block = b) -> torch.Tensor:
                return t.to(DT)[b.sidx][:, b.idx].transpose(0, 1)  # (Gb, Sb, ...)

            dt[..., :b.e] = torch.gather(sel(p.D), 3, b.gather[:, None, None, :].expand(gb, s, n, b.e))
            dt[..., b.e] = sel(p.d0)
            ct[..., :n] = sel(p.C)[:, :, :b.k]
            ct[..., n] = sel(p.c0)[:, :, :b.k]
        return theta.mul_(self.mask)

    def unpack(self, theta: torch.Tensor) -> MLPParams:
        """Flat ``theta (P,)`` -> new batched ``MLPParams`` (``D (S, G, N, d)`` ... ``c0 (S, G, K)``)."""
        s, g, n, d, k = self.shape
        dev = self.mask.device
        theta = theta.detach() * self.mask
        D, d0 = torch.zeros(g, s, n, d, dtype=DT, device=dev), torch.zeros(g, s, n, dtype=DT, device=dev)
        C, c0 = torch.zeros(g, s, k, n, dtype=DT, device=dev), torch.zeros(g, s, k, dtype=DT, device=dev)
        for b in self.blocks:
            gb, sb = len(b.idx), len(b.sidx)
            dt, ct = b.views(theta)
            gi, si = b.idx[:, None], b.sidx[None, :]
            dfull = torch.zeros(gb, sb, n, d, dtype=DT, device=dev)
            D[gi, si] = dfull.scatter_add_(3, b.gather[:, None, None, :].expand(gb, sb, n, b.e), dt[..., :b.e])
            d0[gi, si] = dt[..., b.e]
            C[gi, si, :b.k] = ct[..., :n]
            c0[gi, si, :b.k] = ct[..., n]
        return MLPParams(*(t.transpose(0, 1).contiguous() for t in (D, d0, C, c0)))

    def __call__(self, theta: torch.Tensor, grad: torch.Tensor | None = None) -> float:
        """The objective at ``theta (P,)``; with ``grad (P,)`` also its gradient, written into ``grad``."""
        total = sum(b(theta, grad) for b in self.blocks)
        if grad is not None:
            grad.mul_(self.mask)
        return float(total)


def fit_mlp(x: torch.Tensor, z: torch.Tensor, out_mask: torch.Tensor, sample_weight: torch.Tensor,
            alpha: torch.Tensor, neuron_mask: torch.Tensor, max_iter: int = 500, seed: int = 0,
            history_size: int = 20, chunk: int = 25,
            progress: Callable[[int, float], None] | None = None,
            init_linear: tuple[torch.Tensor, torch.Tensor] | None = None,
            init_gain: float = 0.5, threads: int = 1,
            input_mask: torch.Tensor | None = None,
            device: torch.device | str | None = None) -> tuple[MLPParams, float, int]:
    """Fit the batch; returns masked parameters (float64, on the CPU), the final objective and iterations run.

    ``x (F, d)``, ``z (F, G, K)`` reduced targets, ``out_mask (G, K)`` real output dims,
    ``sample_weight (S, F)``, ``alpha (S, G)``, ``neuron_mask (S, G, N)``.

    ``init_linear = (W (S, G, d, K), b (S, G, K))``: start from a linear model (e.g. the ridge
    fit): its leading singular directions ``W = sum sigma u v^T`` become neurons in their nearly
    linear regime (``D_n = init_gain u_n``, ``C_n = sigma_n v_n / init_gain``, ``tanh(t) ~ t``), so
    L-BFGS starts at (a rank-``N`` truncation of) the linear solution instead of a random point.
    Without it the hidden layer is random and the output layer is fitted by ridge.

    ``input_mask (G, d)``: inputs each cluster may use (per-cluster input selection); the hidden
    weights of the others are held at zero.
    ``threads``: torch intra-op threads while fitting (restored after; 0 leaves torch's setting).
    The L-BFGS two-loop recursion is many small vector ops whose thread synchronisation dominates
    on a busy machine: one thread measured 10x faster on 2 shared cores.
    ``device``: where to fit (None: where ``x`` is); every input is moved there once.
    """
    dev = x.device if device is None else torch.device(device)
    x, z, out_mask, sample_weight, alpha, neuron_mask = (
        t.to(dev) for t in (x, z, out_mask, sample_weight, alpha, neuron_mask))
    input_mask = None if input_mask is None else input_mask.to(dev)
    if init_linear is not None:
        init_linear = (init_linear[0].to(dev), init_linear[1].to(dev))
    before = torch.get_num_threads()
    if threads:
        torch.set_num_threads(threads)
    try:
        params, loss, iters = _fit_mlp(x, z, out_mask, sample_weight, alpha, neuron_mask, max_iter, seed,
                                       history_size, chunk, progress, init_linear, init_gain, input_mask)
        return params.to("cpu"), loss, iters
    finally:
        torch.set_num_threads(before)


def init_params(x: torch.Tensor, z: torch.Tensor, out_mask: torch.Tensor, sample_weight: torch.Tensor,
                alpha: torch.Tensor, neuron_mask: torch.Tensor, seed: int = 0,
                init_linear: tuple[torch.Tensor, torch.Tensor] | None = None, init_gain: float = 0.5,
                input_mask: torch.Tensor | None = None) -> MLPParams:
    """The masked float64 starting point of :func:`fit_mlp` (same arguments; see there), on ``x``'s device (the
    random hidden layer is drawn on the CPU, so every device starts from the same point)."""
    dev = x.device
    x = x.to(DT)
    z = z.to(dev, DT)
    f, d = x.shape
    s, g, n = neuron_mask.shape
    k = z.shape[2]
    check(z.shape[:2] == (f, g), f"mlp fit: targets {tuple(z.shape)} do not match inputs ({f}) / clusters ({g})")
    check(sample_weight.shape == (s, f) and alpha.shape == (s, g), "mlp fit: bad sample_weight/alpha shapes")
    nm = neuron_mask.to(dev, DT)
    im = torch.ones(g, d, dtype=DT, device=dev) if input_mask is None else input_mask.to(dev, DT)
    check_shape(im, (g, d), name="mlp fit: input_mask")
    dm = nm.unsqueeze(-1) * im[None, :, None, :]  # (S, G, N, d) hidden-weight mask
    om = out_mask.to(dev, DT)
    w = sample_weight.to(dev, DT)
    a = alpha.to(dev, DT)
    gen = torch.Generator().manual_seed(int(seed))
    D = torch.randn(s, g, n, d, generator=gen, dtype=DT).to(dev) / max(d, 1) ** 0.5 * dm
    d0 = 0.5 * torch.randn(s, g, n, generator=gen, dtype=DT).to(dev) * nm
    # output layer by weighted ridge on the random hidden activations (exact for that hidden layer)
    h = torch.tanh(torch.einsum("fd,sgnd->sgfn", x, D) + d0.unsqueeze(2)) * nm.unsqueeze(2)
    h1 = torch.cat([h, torch.ones(s, g, f, 1, dtype=DT, device=dev)], dim=3)
    hw = h1 * w[:, None, :, None]
    reg = torch.diag_embed(torch.cat([a.unsqueeze(-1).expand(s, g, n), torch.zeros(s, g, 1, dtype=DT, device=dev)],
                                     -1))
    lhs = hw.transpose(2, 3) @ h1 + reg + 1e-9 * torch.eye(n + 1, dtype=DT, device=dev)
    rhs = hw.transpose(2, 3) @ z.permute(1, 0, 2).unsqueeze(0)  # (S, G, N+1, K)
    sol = torch.linalg.solve(lhs, rhs)
    C = sol[:, :, :n, :].transpose(2, 3) * nm.unsqueeze(2) * om[None, :, :, None]
    c0 = sol[:, :, n, :] * om
    if init_linear is not None:
        w_lin, b_lin = (t.to(dev, DT) for t in init_linear)
        check(w_lin.shape == (s, g, d, k) and b_lin.shape == (s, g, k), "mlp fit: bad init_linear shapes")
        u, sig, vh = torch.linalg.svd(w_lin, full_matrices=False)  # (S,G,d,r) (S,G,r) (S,G,r,K)
        r = min(n, sig.shape[-1])
        D = 0.01 * D
        D[:, :, :r, :] = init_gain * u[..., :r].transpose(2, 3)
        d0 = torch.zeros_like(d0)
        C = torch.zeros_like(C)
        C[:, :, :, :r] = (vh[:, :, :r, :] * (sig[..., :r] / init_gain).unsqueeze(-1)).transpose(2, 3)
        D, C = D * dm, C * nm.unsqueeze(2) * om[None, :, :, None]
        c0 = b_lin * om
    return MLPParams(D, d0, C, c0)


def _fit_mlp(x: torch.Tensor, z: torch.Tensor, out_mask: torch.Tensor, sample_weight: torch.Tensor,
             alpha: torch.Tensor, neuron_mask: torch.Tensor, max_iter: int, seed: int, history_size: int, chunk: int,
             progress: Callable[[int, float], None] | None, init_linear: tuple[torch.Tensor, torch.Tensor] | None,
             init_gain: float, input_mask: torch.Tensor | None = None) -> tuple[MLPParams, float, int]:
    start = init_params(x, z, out_mask, sample_weight, alpha, neuron_mask, seed, init_linear, init_gain, input_mask)
    obj = MLPObjective(x, z, out_mask, sample_weight, alpha, neuron_mask, input_mask)
    theta = obj.pack(start)
    theta.grad = torch.zeros_like(theta)
    # memo of the last evaluation: LBFGS.step re-evaluates the point the previous step ended on, and
    # the chunk loop asks for the objective there too; both are usually the line search's last point
    memo_theta = torch.full_like(theta, float("nan"))
    memo_grad = torch.empty_like(theta)
    memo_loss = [float("nan")]

    def closure() -> float:
        if torch.equal(theta, memo_theta):
            theta.grad.copy_(memo_grad)
            return memo_loss[0]
        memo_loss[0] = obj(theta, theta.grad)
        memo_theta.copy_(theta)
        memo_grad.copy_(theta.grad)
        return memo_loss[0]

    opt = torch.optim.LBFGS([theta], lr=1.0, max_iter=chunk, history_size=history_size,
                            line_search_fn="strong_wolfe", tolerance_grad=1e-10, tolerance_change=1e-14)
    done = 0
    last = float("inf")
    while done < max_iter:
        opt.param_groups[0]["max_iter"] = min(chunk, max_iter - done)
        opt.param_groups[0]["max_eval"] = int(opt.param_groups[0]["max_iter"] * 1.25)
        opt.step(closure)
        n_iter = int(opt.state[opt._params[0]].get("n_iter", done))
        loss = closure()
        if progress is not None:
            progress(n_iter, loss)
        if n_iter <= done or abs(last - loss) <= 1e-13 * max(abs(loss), 1.0):
            done = max(n_iter, done)
            break
        done = n_iter
        last = loss
    loss = closure()
    return obj.unpack(theta), loss, done

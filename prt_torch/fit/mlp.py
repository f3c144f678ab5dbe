"""Fitting per-cluster tanh networks (seed 003 eqs. 12-13) with one L-BFGS over a whole batch.

The batch axes are ``S`` settings (cross-validation fold x alpha, or the single final fit) and
``G`` clusters. Objective, summed over the batch (the terms are independent, so the joint
minimiser is every term's minimiser)::

    sum_{s,g} [ sum_i w_si ||Z~_g(X_i) - Z_ig||^2 + alpha_sg (||C_sg||^2 + ||D_sg||^2) ]

with ``w_si`` 0/1 sample weights (the fold's training frames) and padded output dimensions and
unused neurons masked out. Fit in float64 (``torch.optim.LBFGS`` with strong-Wolfe line search;
float32 L-BFGS stalls, pytorch#49993); the output layer is initialised by ridge on the random
hidden layer's activations.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import torch

from prt_torch.errors import check

DT = torch.float64


@dataclass
class MLPParams:
    """Batched parameters: ``D (S, G, N, d)``, ``d0 (S, G, N)``, ``C (S, G, K, N)``, ``c0 (S, G, K)``."""

    D: torch.Tensor
    d0: torch.Tensor
    C: torch.Tensor
    c0: torch.Tensor


def mlp_forward(x: torch.Tensor, p: MLPParams) -> torch.Tensor:
    """``x (F, d)`` -> ``(S, G, F, K)``."""
    h = torch.tanh(torch.einsum("fd,sgnd->sgfn", x, p.D) + p.d0.unsqueeze(2))
    return torch.einsum("sgfn,sgkn->sgfk", h, p.C) + p.c0.unsqueeze(2)


def fit_mlp(x: torch.Tensor, z: torch.Tensor, out_mask: torch.Tensor, sample_weight: torch.Tensor,
            alpha: torch.Tensor, neuron_mask: torch.Tensor, max_iter: int = 500, seed: int = 0,
            history_size: int = 20, chunk: int = 25,
            progress: Callable[[int, float], None] | None = None,
            init_linear: tuple[torch.Tensor, torch.Tensor] | None = None,
            init_gain: float = 0.5, threads: int = 1,
            input_mask: torch.Tensor | None = None) -> tuple[MLPParams, float, int]:
    """Fit the batch; returns masked parameters (float64), the final objective and iterations run.

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
    """
    before = torch.get_num_threads()
    if threads:
        torch.set_num_threads(threads)
    try:
        return _fit_mlp(x, z, out_mask, sample_weight, alpha, neuron_mask, max_iter, seed, history_size, chunk,
                        progress, init_linear, init_gain, input_mask)
    finally:
        torch.set_num_threads(before)


def _fit_mlp(x: torch.Tensor, z: torch.Tensor, out_mask: torch.Tensor, sample_weight: torch.Tensor,
             alpha: torch.Tensor, neuron_mask: torch.Tensor, max_iter: int, seed: int, history_size: int, chunk: int,
             progress: Callable[[int, float], None] | None, init_linear: tuple[torch.Tensor, torch.Tensor] | None,
             init_gain: float, input_mask: torch.Tensor | None = None) -> tuple[MLPParams, float, int]:
    x = x.to(DT)
    z = z.to(DT)
    f, d = x.shape
    s, g, n = neuron_mask.shape
    k = z.shape[2]
    check(z.shape[:2] == (f, g), f"mlp fit: targets {tuple(z.shape)} do not match inputs ({f}) / clusters ({g})")
    check(sample_weight.shape == (s, f) and alpha.shape == (s, g), "mlp fit: bad sample_weight/alpha shapes")
    nm = neuron_mask.to(DT)
    im = torch.ones(g, d, dtype=DT) if input_mask is None else input_mask.to(DT)
    check(im.shape == (g, d), f"mlp fit: input_mask must be ({g}, {d}), got {tuple(im.shape)}")
    dm = nm.unsqueeze(-1) * im[None, :, None, :]  # (S, G, N, d) hidden-weight mask
    om = out_mask.to(DT)
    w = sample_weight.to(DT)
    a = alpha.to(DT)
    gen = torch.Generator().manual_seed(int(seed))
    D = torch.randn(s, g, n, d, generator=gen, dtype=DT) / max(d, 1) ** 0.5 * dm
    d0 = 0.5 * torch.randn(s, g, n, generator=gen, dtype=DT) * nm
    # output layer by weighted ridge on the random hidden activations (exact for that hidden layer)
    h = torch.tanh(torch.einsum("fd,sgnd->sgfn", x, D) + d0.unsqueeze(2)) * nm.unsqueeze(2)
    h1 = torch.cat([h, torch.ones(s, g, f, 1, dtype=DT)], dim=3)
    hw = h1 * w[:, None, :, None]
    reg = torch.diag_embed(torch.cat([a.unsqueeze(-1).expand(s, g, n), torch.zeros(s, g, 1, dtype=DT)], -1))
    lhs = hw.transpose(2, 3) @ h1 + reg + 1e-9 * torch.eye(n + 1, dtype=DT)
    rhs = hw.transpose(2, 3) @ z.permute(1, 0, 2).unsqueeze(0)  # (S, G, N+1, K)
    sol = torch.linalg.solve(lhs, rhs)
    C = sol[:, :, :n, :].transpose(2, 3) * nm.unsqueeze(2) * om[None, :, :, None]
    c0 = sol[:, :, n, :] * om
    if init_linear is not None:
        w_lin, b_lin = (t.to(DT) for t in init_linear)
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
    params = [t.clone().requires_grad_(True) for t in (D, d0, C, c0)]
    zt = z.permute(1, 0, 2).unsqueeze(0)  # (1, G, F, K)
    masks = (dm, nm, nm.unsqueeze(2) * om[None, :, :, None], om.expand(s, g, k))

    def masked() -> MLPParams:
        return MLPParams(*(p * m for p, m in zip(params, masks, strict=True)))

    def objective() -> torch.Tensor:
        p = masked()
        r = (mlp_forward(x, p) - zt) * om[None, :, None, :]
        data = (r.pow(2).sum(-1) * w[:, None, :]).sum()
        pen = (a * (p.C.pow(2).sum((2, 3)) + p.D.pow(2).sum((2, 3)))).sum()
        return data + pen

    opt = torch.optim.LBFGS(params, lr=1.0, max_iter=chunk, history_size=history_size,
                            line_search_fn="strong_wolfe", tolerance_grad=1e-10, tolerance_change=1e-14)

    def closure() -> torch.Tensor:
        opt.zero_grad()
        loss = objective()
        loss.backward()
        return loss

    done = 0
    last = float("inf")
    while done < max_iter:
        opt.param_groups[0]["max_iter"] = min(chunk, max_iter - done)
        opt.param_groups[0]["max_eval"] = int(opt.param_groups[0]["max_iter"] * 1.25)
        opt.step(closure)
        n_iter = int(opt.state[opt._params[0]].get("n_iter", done))
        with torch.no_grad():
            loss = float(objective())
        if progress is not None:
            progress(n_iter, loss)
        if n_iter <= done or abs(last - loss) <= 1e-13 * max(abs(loss), 1.0):
            done = max(n_iter, done)
            break
        done = n_iter
        last = loss
    with torch.no_grad():
        final = masked()
        loss = float(objective())
    return MLPParams(*(t.detach() for t in (final.D, final.d0, final.C, final.c0))), loss, done


def mlp_predict(x: torch.Tensor, p: MLPParams) -> torch.Tensor:
    """``x (F, d)`` -> ``(S, G, F, K)`` without gradients."""
    with torch.no_grad():
        return mlp_forward(x.to(p.D.dtype), p)

"""The analytic, allocation-free eq. 13 objective (:class:`MLPObjective`) against the plain autograd reference."""

from __future__ import annotations

import torch

from prt_torch.fit.mlp import MLPObjective, MLPParams, fit_mlp, init_params, mlp_forward, reference_objective

DT = torch.float64


def _problem(s: int = 3, g: int = 4, n: int = 5, d: int = 7, k: int = 6, f: int = 50, seed: int = 0) -> dict:
    """Random data with every mask in play: unselected inputs, unused neurons, padded outputs, 0/1 weights."""
    gen = torch.Generator().manual_seed(seed)
    x = torch.randn(f, d, generator=gen, dtype=DT)
    z = torch.randn(f, g, k, generator=gen, dtype=DT)
    out_mask = (torch.rand(g, k, generator=gen) < 0.7).to(DT)
    out_mask[:, 0] = 1.0
    neuron_mask = (torch.rand(s, g, n, generator=gen) < 0.7).to(DT)
    neuron_mask[..., 0] = 1.0
    input_mask = torch.rand(g, d, generator=gen) < 0.6
    input_mask[:, 0] = True
    input_mask[0] = True  # one cluster uses every input
    sample_weight = (torch.rand(s, f, generator=gen) < 0.75).to(DT)
    alpha = torch.rand(s, g, generator=gen, dtype=DT) * 3
    dm = neuron_mask[..., None] * input_mask.to(DT)[None, :, None, :]
    cm = neuron_mask[:, :, None, :] * out_mask[None, :, :, None]
    p = MLPParams(torch.randn(s, g, n, d, generator=gen, dtype=DT) * dm,
                  torch.randn(s, g, n, generator=gen, dtype=DT) * neuron_mask,
                  torch.randn(s, g, k, n, generator=gen, dtype=DT) * cm,
                  torch.randn(s, g, k, generator=gen, dtype=DT) * out_mask)
    return {"x": x, "z": z, "out_mask": out_mask, "sample_weight": sample_weight, "alpha": alpha,
            "neuron_mask": neuron_mask, "input_mask": input_mask, "p": p,
            "masks": (dm, neuron_mask, cm, out_mask.expand(s, g, k))}


def test_gradient_matches_autograd_of_reference() -> None:
    for seed, block_cost, max_groups in ((0, 3e6, 8), (1, 0.0, 8), (2, 0.0, 0), (3, 3e6, 0)):
        pb = _problem(seed=seed)
        obj = MLPObjective(pb["x"], pb["z"], pb["out_mask"], pb["sample_weight"], pb["alpha"], pb["neuron_mask"],
                           pb["input_mask"], block_cost=block_cost, max_groups=max_groups)
        theta = obj.pack(pb["p"])
        grad = torch.full_like(theta, float("nan"))
        loss = obj(theta, grad)
        # the reference in the old parametrisation: free parameters times their masks
        free = [t.clone().requires_grad_(True) for t in (pb["p"].D, pb["p"].d0, pb["p"].C, pb["p"].c0)]
        masked = MLPParams(*(t * m for t, m in zip(free, pb["masks"], strict=True)))
        ref = reference_objective(pb["x"], pb["z"], pb["out_mask"], pb["sample_weight"], pb["alpha"], masked)
        ref_grad = torch.autograd.grad(ref, free)
        assert abs(loss - ref.item()) <= 1e-12 * abs(ref.item())
        assert obj(theta) == loss  # the loss-only path gives the same number
        got = obj.unpack(grad)
        for name, a, b in zip("D d0 C c0".split(), (got.D, got.d0, got.C, got.c0), ref_grad, strict=True):
            err = float((a - b).abs().max())
            assert err <= 1e-10 * max(1.0, float(b.abs().max())), (seed, name, err)
        # masked coordinates: exactly zero gradient (L-BFGS never moves them)
        assert float((grad * (1 - obj.mask)).abs().max()) == 0.0


def test_pack_unpack_round_trip() -> None:
    pb = _problem(seed=4)
    obj = MLPObjective(pb["x"], pb["z"], pb["out_mask"], pb["sample_weight"], pb["alpha"], pb["neuron_mask"],
                       pb["input_mask"], block_cost=0.0)
    assert len(obj.blocks) > 1
    back = obj.unpack(obj.pack(pb["p"]))
    for a, b in zip((back.D, back.d0, back.C, back.c0), (pb["p"].D, pb["p"].d0, pb["p"].C, pb["p"].c0), strict=True):
        assert torch.equal(a, b)
    for b in obj.blocks:  # a block's hidden layer spans the most inputs one of its clusters uses
        assert b.e == int(pb["input_mask"][b.idx].sum(1).max())
    pairs = sorted((g, s) for b in obj.blocks for g in b.idx.tolist() for s in b.sidx.tolist())
    assert pairs == [(g, s) for g in range(pb["z"].shape[1]) for s in range(pb["sample_weight"].shape[0])]
    # one block per cluster vs everything in one block: the same objective and gradient
    args = (pb["x"], pb["z"], pb["out_mask"], pb["sample_weight"], pb["alpha"], pb["neuron_mask"], pb["input_mask"])
    one = MLPObjective(*args, max_blocks=1, max_groups=0)  # all settings on all frames in one block
    assert len(one.blocks) == 1
    ga, gb = torch.empty(obj.size, dtype=DT), torch.empty(one.size, dtype=DT)
    la, lb = obj(obj.pack(pb["p"]), ga), one(one.pack(pb["p"]), gb)
    assert abs(la - lb) <= 1e-12 * abs(la)
    for a, b in zip(obj.unpack(ga).__dict__.values(), one.unpack(gb).__dict__.values(), strict=True):
        assert torch.allclose(a, b, rtol=1e-12, atol=1e-12)


def test_evaluation_allocates_nothing_large() -> None:
    """The inner loop writes into buffers made once: no tensor storage beyond scalars is allocated."""
    pb = _problem(s=4, g=3, n=8, d=9, k=7, f=300, seed=5)
    obj = MLPObjective(pb["x"], pb["z"], pb["out_mask"], pb["sample_weight"], pb["alpha"], pb["neuron_mask"],
                       pb["input_mask"])
    theta = obj.pack(pb["p"])
    grad = torch.empty_like(theta)
    obj(theta, grad)
    with torch.profiler.profile(activities=[torch.profiler.ProfilerActivity.CPU], profile_memory=True) as prof:
        for _ in range(3):
            obj(theta, grad)
    allocated = [e.cpu_memory_usage for e in prof.events() if e.cpu_memory_usage > 0]
    assert max(allocated, default=0) <= 64, allocated  # 0-d results only (the loss scalars)


def _reference_fit(pb: dict, start: MLPParams, max_iter: int, chunk: int = 25) -> tuple[MLPParams, float]:
    """The previous implementation: autograd of the reference objective on ``params * mask``, same L-BFGS."""
    params = [t.clone().requires_grad_(True) for t in (start.D, start.d0, start.C, start.c0)]

    def masked() -> MLPParams:
        return MLPParams(*(p * m for p, m in zip(params, pb["masks"], strict=True)))

    def objective() -> torch.Tensor:
        return reference_objective(pb["x"], pb["z"], pb["out_mask"], pb["sample_weight"], pb["alpha"], masked())

    opt = torch.optim.LBFGS(params, lr=1.0, max_iter=chunk, history_size=20, line_search_fn="strong_wolfe",
                            tolerance_grad=1e-10, tolerance_change=1e-14)

    def closure() -> torch.Tensor:
        opt.zero_grad()
        loss = objective()
        loss.backward()
        return loss

    done, last = 0, float("inf")
    while done < max_iter:
        opt.param_groups[0]["max_iter"] = min(chunk, max_iter - done)
        opt.param_groups[0]["max_eval"] = int(opt.param_groups[0]["max_iter"] * 1.25)
        opt.step(closure)
        n_iter = int(opt.state[opt._params[0]].get("n_iter", done))
        with torch.no_grad():
            loss = float(objective())
        if n_iter <= done or abs(last - loss) <= 1e-13 * max(abs(loss), 1.0):
            break
        done, last = n_iter, loss
    with torch.no_grad():
        return MLPParams(*(t.detach() for t in (masked().D, masked().d0, masked().C, masked().c0))), float(objective())


def test_fit_matches_autograd_implementation() -> None:
    """Same start, same L-BFGS settings: the fitted models agree to optimiser tolerance."""
    pb = _problem(s=2, g=3, n=4, d=5, k=4, f=80, seed=6)
    pb["z"] = torch.tanh(pb["z"])
    args = (pb["x"], pb["z"], pb["out_mask"], pb["sample_weight"], pb["alpha"], pb["neuron_mask"])
    start = init_params(*args, seed=2, input_mask=pb["input_mask"])
    ref, ref_loss = _reference_fit(pb, start, max_iter=60)
    got, loss, iters = fit_mlp(*args, max_iter=60, seed=2, input_mask=pb["input_mask"])
    assert iters > 0
    assert abs(loss - ref_loss) <= 1e-6 * ref_loss, (loss, ref_loss)
    pred, ref_pred = mlp_forward(pb["x"], got), mlp_forward(pb["x"], ref)
    assert float((pred - ref_pred).norm() / ref_pred.norm()) < 1e-4

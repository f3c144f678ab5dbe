"""Batched L-BFGS fitting of eq. 12/13: separability across the batch and recovery of a teacher."""

from __future__ import annotations

import numpy as np
import torch

from prt_torch.fit.mlp import MLPParams, fit_mlp, mlp_forward


def _teacher(f: int = 120, d: int = 3, g: int = 2, k: int = 2, seed: int = 0) -> tuple[torch.Tensor, torch.Tensor]:
    gen = torch.Generator().manual_seed(seed)
    x = torch.rand(f, d, generator=gen, dtype=torch.float64) * 4 - 2
    p = MLPParams(torch.randn(1, g, 3, d, generator=gen, dtype=torch.float64),
                  torch.randn(1, g, 3, generator=gen, dtype=torch.float64),
                  torch.randn(1, g, k, 3, generator=gen, dtype=torch.float64),
                  torch.randn(1, g, k, generator=gen, dtype=torch.float64))
    z = mlp_forward(x, p)[0].permute(1, 0, 2)  # (F, G, K)
    return x, z


def test_recovers_teacher_network() -> None:
    x, z = _teacher()
    params, loss, _ = fit_mlp(x, z, torch.ones(2, 2), torch.ones(1, x.shape[0]), torch.full((1, 2), 1e-8),
                              torch.ones(1, 2, 6), max_iter=400, seed=3)
    pred = mlp_forward(x, params)[0].permute(1, 0, 2)
    rel = float((pred - z).norm() / z.norm())
    assert rel < 1e-2, rel  # measured 1.5e-3 at 400 iterations (3e-5 at 1500)
    lin = np.linalg.lstsq(np.c_[x.numpy(), np.ones(len(x))], z.reshape(len(x), -1).numpy(), rcond=None)[0]
    lin_rel = np.linalg.norm(np.c_[x.numpy(), np.ones(len(x))] @ lin - z.reshape(len(x), -1).numpy()) / float(z.norm())
    assert lin_rel > 10 * rel, (lin_rel, rel)


def test_batch_is_separable() -> None:
    """Fitting clusters jointly reaches (to tolerance) the optimum of fitting each alone; masks zero
    the unused neurons and padded outputs."""
    x, z = _teacher(g=2, seed=1)
    om = torch.tensor([[1.0, 1.0], [1.0, 0.0]])
    nm = torch.tensor([[[1.0, 1, 1, 1], [1, 1, 0, 0]]])
    alpha = torch.tensor([[1e-2, 1e-1]])
    joint, _, _ = fit_mlp(x, z, om, torch.ones(1, len(x)), alpha, nm, max_iter=600, seed=0)
    assert float(joint.C[0, 1, 1].abs().max()) == 0.0 and float(joint.C[0, 1, :, 2:].abs().max()) == 0.0

    def objective(p: MLPParams, g: int) -> float:
        r = (mlp_forward(x, p)[0, g] - z[:, g]) * om[g]
        return float(r.pow(2).sum() + alpha[0, g] * (p.C[0, g].pow(2).sum() + p.D[0, g].pow(2).sum()))

    for g in range(2):
        alone, _, _ = fit_mlp(x, z[:, g:g + 1], om[g:g + 1], torch.ones(1, len(x)), alpha[:, g:g + 1],
                              nm[:, g:g + 1], max_iter=600, seed=0)
        x_obj = float(((mlp_forward(x, alone)[0, 0] - z[:, g]) * om[g]).pow(2).sum()
                      + alpha[0, g] * (alone.C.pow(2).sum() + alone.D.pow(2).sum()))
        j_obj = objective(joint, g)
        assert abs(j_obj - x_obj) <= 0.05 * max(x_obj, 1e-6) + 1e-6, (g, j_obj, x_obj)


def test_masks_survive_the_fit() -> None:
    """Unselected inputs, unused neurons and padded outputs come back exactly zero; the rest is fitted."""
    x, z = _teacher(d=4, g=3, k=3, seed=2)
    om = torch.tensor([[1.0, 1, 1], [1, 1, 0], [1, 0, 0]])
    nm = torch.tensor([[[1.0, 1, 1, 1], [1, 1, 0, 0], [1, 1, 1, 0]]])
    im = torch.tensor([[True, True, True, True], [True, False, True, False], [False, False, False, True]])
    p, loss, iters = fit_mlp(x, z, om, torch.ones(1, len(x)), torch.full((1, 3), 1e-3), nm, max_iter=50, seed=1,
                             input_mask=im)
    assert iters > 0 and np.isfinite(loss)
    dm = nm[..., None] * im.double()[None, :, None, :]
    assert float((p.D * (1 - dm)).abs().max()) == 0.0
    assert float((p.C * (1 - nm[:, :, None, :] * om[None, :, :, None])).abs().max()) == 0.0
    assert float((p.c0 * (1 - om)).abs().max()) == 0.0 and float((p.d0 * (1 - nm)).abs().max()) == 0.0
    assert float(p.D[0, 1][:, [0, 2]][:2].abs().min()) > 0.0  # the selected inputs of used neurons move

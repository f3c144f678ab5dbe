"""Regressors from reduced pose ``X (B, d)`` to reduced visibility ``Z (B, G, K)``, batched over
the ``G`` output clusters (groups). All share one interface: ``forward(X) -> Z`` plus
``config() -> dict`` (constructor arguments, JSON-able) so a model is saved as state dict + config.

* :class:`LinearRegressor`: ``Z_g = X W_g + b_g`` (ridge / Tikhonov fit, seed 000 section 4).
* :class:`QuadraticRegressor`: the same on ``[X, X_i X_j (i <= j)]`` (quadratic features).
* :class:`MLPRegressor`: seed 003 eq. 12 per cluster,
  ``Z_g = sum_n c_gn tanh(d_gn . X + d0_gn) + c0_g``, parameters ``(G, N, d)`` / ``(G, K, N)``.
"""

from __future__ import annotations

from typing import Any

import torch
from torch import nn


def quadratic_index(d: int) -> torch.Tensor:
    """Flat indices ``i * d + j`` (``i <= j``) into ``outer(X, X)``: ``(d (d + 1) / 2,)`` int64."""
    i, j = torch.triu_indices(d, d)
    return (i * d + j).to(torch.int64)


def quadratic_features(x: torch.Tensor, index: torch.Tensor | None = None) -> torch.Tensor:
    """``x (B, d) -> (B, d + d (d + 1) / 2)``: ``[x, x_i x_j for i <= j]``."""
    d = x.shape[1]
    if index is None:
        index = quadratic_index(d).to(x.device)
    outer = (x.unsqueeze(2) * x.unsqueeze(1)).reshape(x.shape[0], d * d)
    return torch.cat([x, outer.index_select(1, index)], dim=1)


class LinearRegressor(nn.Module):
    """``Z (B, G, K) = X (B, d) @ weight (d, G, K) + bias (G, K)``."""

    kind = "linear"

    def __init__(self, in_dim: int, n_groups: int, width: int) -> None:
        super().__init__()
        self.in_dim, self.n_groups, self.width = int(in_dim), int(n_groups), int(width)
        self.weight = nn.Parameter(torch.zeros(self.feature_dim, self.n_groups, self.width))
        self.bias = nn.Parameter(torch.zeros(self.n_groups, self.width))

    @property
    def feature_dim(self) -> int:
        return self.in_dim

    def features(self, x: torch.Tensor) -> torch.Tensor:
        return x

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        f = self.features(x)
        z = f @ self.weight.reshape(self.feature_dim, -1)
        return z.reshape(x.shape[0], self.n_groups, self.width) + self.bias

    def config(self) -> dict[str, Any]:
        return {"in_dim": self.in_dim, "n_groups": self.n_groups, "width": self.width}


class QuadraticRegressor(LinearRegressor):
    """Ridge on quadratic features of the reduced input: ``d + d (d + 1) / 2`` features."""

    kind = "quadratic"

    def __init__(self, in_dim: int, n_groups: int, width: int) -> None:
        super().__init__(in_dim, n_groups, width)
        self.register_buffer("qindex", quadratic_index(self.in_dim), persistent=False)

    @property
    def feature_dim(self) -> int:
        return self.in_dim + self.in_dim * (self.in_dim + 1) // 2

    def features(self, x: torch.Tensor) -> torch.Tensor:
        return quadratic_features(x, self.qindex)


class MLPRegressor(nn.Module):
    """Per-cluster single-hidden-layer tanh network (seed 003 eq. 12), batched over clusters.

    ``hidden_weight (G, N, d)``, ``hidden_bias (G, N)``, ``out_weight (G, K, N)``, ``out_bias (G, K)``.
    Clusters that chose fewer than ``N`` neurons carry zero output weights for the unused units.
    """

    kind = "mlp"

    def __init__(self, in_dim: int, n_groups: int, width: int, neurons: int) -> None:
        super().__init__()
        self.in_dim, self.n_groups, self.width, self.neurons = int(in_dim), int(n_groups), int(width), int(neurons)
        self.hidden_weight = nn.Parameter(torch.zeros(self.n_groups, self.neurons, self.in_dim))
        self.hidden_bias = nn.Parameter(torch.zeros(self.n_groups, self.neurons))
        self.out_weight = nn.Parameter(torch.zeros(self.n_groups, self.width, self.neurons))
        self.out_bias = nn.Parameter(torch.zeros(self.n_groups, self.width))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        h = torch.tanh(torch.einsum("bd,gnd->bgn", x, self.hidden_weight) + self.hidden_bias)
        return torch.einsum("bgn,gkn->bgk", h, self.out_weight) + self.out_bias

    def config(self) -> dict[str, Any]:
        return {"in_dim": self.in_dim, "n_groups": self.n_groups, "width": self.width, "neurons": self.neurons}


REGRESSORS: dict[str, type[nn.Module]] = {
    "linear": LinearRegressor,
    "quadratic": QuadraticRegressor,
    "mlp": MLPRegressor,
}

"""The fixed linear ends of a visibility model: input PCA projection and output PCA unprojection.

Both are buffers-only ``nn.Module`` s (dense matmul + one gather), ONNX-exportable.
"""

from __future__ import annotations

import numpy as np
import torch
from torch import nn


class InputProjection(nn.Module):
    """Pose features ``x (B, A)`` -> reduced input ``X (B, d)`` = ``(x - mean) @ proj``.

    ``proj (A, d)`` is the input PCA's components divided by their scale (seed 003 section 5.2,
    ``X = P_i (x - mean)``, optionally whitened).
    """

    def __init__(self, mean: torch.Tensor | np.ndarray, proj: torch.Tensor | np.ndarray) -> None:
        super().__init__()
        self.register_buffer("mean", torch.as_tensor(np.asarray(mean), dtype=torch.float32))
        self.register_buffer("proj", torch.as_tensor(np.asarray(proj), dtype=torch.float32))

    @property
    def in_dim(self) -> int:
        return int(self.proj.shape[0])

    @property
    def out_dim(self) -> int:
        return int(self.proj.shape[1])

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return (x - self.mean) @ self.proj


class OutputUnprojection(nn.Module):
    """Reduced outputs ``z (B, G, Kmax)`` -> visibility ``(B, V, C)``.

    ``basis (G, Kmax, Lmax)`` per-group (cluster) scaled components, ``gather (V*C,)`` int32
    indices into the flattened ``(G * Lmax)`` group outputs, ``mean (V*C,)``. One batched matmul
    and one ``index_select``; no scatter, no sparse tensors.
    """

    def __init__(self, basis: torch.Tensor | np.ndarray, gather: torch.Tensor | np.ndarray,
                 mean: torch.Tensor | np.ndarray, n_vertices: int, n_coeffs: int) -> None:
        super().__init__()
        self.register_buffer("basis", torch.as_tensor(np.asarray(basis), dtype=torch.float32))
        self.register_buffer("gather", torch.as_tensor(np.asarray(gather), dtype=torch.int32))
        self.register_buffer("mean", torch.as_tensor(np.asarray(mean), dtype=torch.float32))
        self.n_vertices = int(n_vertices)
        self.n_coeffs = int(n_coeffs)

    def forward(self, z: torch.Tensor) -> torch.Tensor:
        b = z.shape[0]
        y = torch.einsum("bgk,gkl->bgl", z, self.basis).reshape(b, -1)
        out = y.index_select(1, self.gather) + self.mean
        return out.reshape(b, self.n_vertices, self.n_coeffs)


class GlobalUnprojection(nn.Module):
    """Seed 000 section 5 output: reduced ``z (B, 1, C * k)`` -> ``(B, V, C)``.

    ``basis (k, V)`` shared by every SH coefficient (scaled components of the PCA over the
    per-coefficient vertex vectors), ``mean (V * C,)``: ``v[:, :, c] = mean + z[:, c, :] @ basis``.
    """

    def __init__(self, basis: torch.Tensor | np.ndarray, mean: torch.Tensor | np.ndarray, n_vertices: int,
                 n_coeffs: int) -> None:
        super().__init__()
        self.register_buffer("basis", torch.as_tensor(np.asarray(basis), dtype=torch.float32))
        self.register_buffer("mean", torch.as_tensor(np.asarray(mean), dtype=torch.float32))
        self.n_vertices = int(n_vertices)
        self.n_coeffs = int(n_coeffs)

    def forward(self, z: torch.Tensor) -> torch.Tensor:
        b = z.shape[0]
        y = z.reshape(b, self.n_coeffs, -1) @ self.basis  # (B, C, V)
        return y.transpose(1, 2).reshape(b, -1).add(self.mean).reshape(b, self.n_vertices, self.n_coeffs)

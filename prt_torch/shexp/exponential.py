"""The SH exponential of log-visibility vectors (Ren et al. 2006 sec. 4): optimal linear (OL) and HYB.

Both isolate the DC term first: ``exp*(f) = exp(f_0 / sqrt(4 pi)) exp*(f^)``, ``f^ = f`` with ``f_0 = 0``
(exact: the DC term is a constant factor). Then, with ``m = ||f^||``:

* ``"ol"``: ``exp*(f^) ~= a(m) 1 + b(m) f^`` (table :func:`prt_torch.shexp.tables.ol_table`);
* ``"hyb"``: ``k = max(0, ceil(log2(m / HYB_THRESHOLD)))`` (at most ``MAX_SQUARINGS``), OL of
  ``f^ / 2^k``, then ``k`` SH self-products ``g <- g * g`` (:mod:`prt_torch.sh.product`), scaling and
  squaring. Elements need different ``k``: every element runs the same fixed number of squaring steps and
  keeps its value once its own ``k`` is done (a 0/1 mask, :func:`squarings`); the step count is the largest
  ``k`` present (an ONNX ``Loop`` in the exported graph, so a batch that needs 6 steps runs 6, not 10).

**The squaring** is the projected SH product ``(g * g)_k = sum_ij Gamma_kij g_i g_j`` computed through point
values: ``g`` evaluated at the ``Q`` nodes of a rule exact for degree ``3(n-1)`` (Lebedev, 38 nodes at order 4),
squared, projected back (``(g Y^T)^2 (w Y)``): exactly the Gaunt product (``sh.product`` builds its Gaunt
tensor from such a rule), as two dense ``(C, Q)`` matmuls, ``2 C Q`` multiply-adds per element instead of the
``C^3 + C^2`` of the dense ``(C, C*C)`` Gaunt matrix (1216 vs 4352 at order 4).

Torch only (float32 at run time); the tables are built in float64 and cached per order.
"""

from __future__ import annotations

import functools
import math

import numpy as np
import torch

from prt_torch.errors import PrtError
from prt_torch.scene.shexp_kernel import HYB_THRESHOLD, MAX_SQUARINGS, OL_MAX
from prt_torch.sh.basis import sh_basis
from prt_torch.sh.quadrature import sphere_quadrature
from prt_torch.shexp.tables import N_OL, ol_table

METHODS = ("hyb", "ol")


def check_method(method: str) -> str:
    """``method`` if it is one of :data:`METHODS`, else a one-line :class:`PrtError`."""
    if method not in METHODS:
        raise PrtError(f"unknown SH exponential method {method!r}; expected one of {', '.join(METHODS)}")
    return method


@functools.cache
def _ol_numpy(order: int) -> np.ndarray:
    return np.ascontiguousarray(ol_table(order), dtype=np.float32)


def interp_table(table: torch.Tensor, u: torch.Tensor) -> torch.Tensor:
    """Linear interpolation of ``table (N, D)`` at ``u (...)`` in ``[0, 1]`` (row ``i`` at ``i/(N-1)``,
    clamped) -> ``(..., D)``. ONNX-friendly (floor, gather)."""
    n = table.shape[0]
    x = u.clamp(0.0, 1.0) * (n - 1)
    i0 = torch.floor(x).clamp(max=n - 2)
    w = (x - i0)[..., None]
    i0 = i0.to(torch.int32)  # onnxruntime gathers int32 indices ~4x faster than int64
    return torch.nn.functional.embedding(i0, table) * (1.0 - w) + torch.nn.functional.embedding(i0 + 1, table) * w


def ol_coefficients(mag: torch.Tensor, ol: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """``a(m), b(m)`` (each shaped like ``mag``) from the OL table ``ol (N_OL, 2)`` (``m_i = OL_MAX (i/(N-1))^2``)."""
    ab = interp_table(ol, torch.sqrt(mag / OL_MAX))
    return ab[..., 0], ab[..., 1]


@functools.cache
def square_operators(order: int) -> tuple[np.ndarray, np.ndarray]:
    """``(to_points (C, Q), from_points (Q, C))`` float32 of the projected self-product (module doc): the SH basis
    at the nodes of :func:`prt_torch.sh.quadrature.sphere_quadrature` ``(3 (n - 1))`` (transposed), and the same
    times the node weights. ``(g @ to_points) ** 2 @ from_points`` is ``g * g`` (Gaunt)."""
    dirs, w = sphere_quadrature(3 * (order - 1))
    y = sh_basis(dirs, order, check=False)  # (Q, C) float64
    return (np.ascontiguousarray(y.T, dtype=np.float32), np.ascontiguousarray(y * w[:, None], dtype=np.float32))


def sh_square(g: torch.Tensor, to_points: torch.Tensor, from_points: torch.Tensor) -> torch.Tensor:
    """Projected SH self-product ``g * g`` of ``g (..., C)`` through point values (:func:`square_operators`)."""
    h = g @ to_points
    return (h * h) @ from_points


def squarings(g: torch.Tensor, k: torch.Tensor, to_points: torch.Tensor, from_points: torch.Tensor) -> torch.Tensor:
    """``g (..., C)`` squared ``k (...)`` times per element (:func:`sh_square`): ``max(k)`` steps for all, each
    element masked out once its own count is done. The mask is arithmetic (onnxruntime's ``Where`` is ~50x slower
    than a ``Mul``): ``g <- sq(m g) + (1 - m) g`` with ``m`` 0/1; squaring ``m g`` rather than ``g`` keeps
    finished elements from overflowing (``sq(m g) = m sq(g)``); the first ``min(k)`` steps, where every element
    squares, skip the mask. TorchScript-compatible: exported as two ONNX ``Loop`` s whose trip counts are the batch's
    ``min(k)`` and ``max(k) - min(k)`` (:func:`_scripted_squarings`)."""
    kf = k.flatten()
    lo = int(torch.cat([kf, torch.full((1,), 1e9, dtype=k.dtype, device=k.device)]).min().to(torch.int64))
    hi = int(torch.cat([kf, torch.zeros(1, dtype=k.dtype, device=k.device)]).max().to(torch.int64))
    for _step in range(min(lo, hi)):  # every element squares: no mask
        h = g @ to_points
        g = (h * h) @ from_points
    for step in range(min(lo, hi), hi):  # a loop over squaring steps, not over elements
        gm = g * (k > step).to(g.dtype).unsqueeze(-1)  # (1 - m) g = g - m g: one broadcast product per step
        h = gm @ to_points
        g = (h * h) @ from_points + (g - gm)
    return g


@functools.cache
def _scripted_squarings():  # noqa: ANN202 (a torch.jit.ScriptFunction)
    """:func:`squarings` compiled by TorchScript (once, lazily: only ONNX export needs it), so that the legacy
    exporter writes its data-dependent trip count as a ``Loop`` instead of unrolling ``MAX_SQUARINGS`` steps."""
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)
        return torch.jit.script(squarings)


class SHExponential(torch.nn.Module):
    """``exp*(f)`` of ``f (..., C)`` by OL or HYB (module doc). Buffers: the OL table and the two squaring
    operators (:func:`square_operators`)."""

    def __init__(self, order: int, method: str = "hyb", max_squarings: int = MAX_SQUARINGS) -> None:
        super().__init__()
        self.order = int(order)
        self.method = check_method(method)
        self.max_squarings = int(max_squarings)
        self.register_buffer("ol", torch.from_numpy(_ol_numpy(self.order)), persistent=False)
        to_pts, from_pts = square_operators(self.order)
        self.register_buffer("to_points", torch.from_numpy(to_pts), persistent=False)
        self.register_buffer("from_points", torch.from_numpy(from_pts), persistent=False)
        assert self.ol.shape[0] == N_OL

    def forward(self, f: torch.Tensor) -> torch.Tensor:
        f0 = f[..., :1]
        fh = torch.cat([torch.zeros_like(f0), f[..., 1:]], dim=-1)
        mag = torch.linalg.vector_norm(fh, dim=-1)
        ol = self.ol.to(f.dtype)
        if self.method == "ol":
            a, b = ol_coefficients(mag, ol)
            g = b[..., None] * fh
            g = torch.cat([g[..., :1] + (a * math.sqrt(4 * math.pi))[..., None], g[..., 1:]], dim=-1)
            return g * torch.exp(f0 / math.sqrt(4 * math.pi))
        k = torch.ceil(torch.log2(torch.clamp(mag / HYB_THRESHOLD, min=1.0))).clamp(0, self.max_squarings)
        scaled = fh * torch.pow(2.0, -k)[..., None]
        a, b = ol_coefficients(mag * torch.pow(2.0, -k), ol)
        to_pts, from_pts = self.to_points.to(f.dtype), self.from_points.to(f.dtype)
        g = b[..., None] * scaled
        g = torch.cat([g[..., :1] + (a * math.sqrt(4 * math.pi))[..., None], g[..., 1:]], dim=-1)
        if torch.jit.is_tracing() or torch.onnx.is_in_onnx_export():
            g = _scripted_squarings()(g, k, to_pts, from_pts)  # an ONNX Loop of max(k) steps
        else:
            g = squarings(g, k, to_pts, from_pts)
        return g * torch.exp(f0 / math.sqrt(4 * math.pi))


def sh_exp(f: torch.Tensor, method: str = "hyb") -> torch.Tensor:
    """Functional form of :class:`SHExponential` for ``f (..., C)`` (order from ``C``)."""
    c = int(f.shape[-1])
    n = int(round(math.sqrt(c)))
    if n * n != c or not 1 <= n <= 8:
        raise PrtError(f"SH exponential needs (..., C) with C = n*n, n in 1..8; got last dimension {c}")
    if f.dtype not in (torch.float32, torch.float64):
        f = f.to(torch.float32)
    return _module(n, check_method(method)).to(f.device)(f)


@functools.cache
def _module(order: int, method: str) -> SHExponential:
    return SHExponential(order, method)

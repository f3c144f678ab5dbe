"""Local visibility: one small network shared by every vertex, fed the shape of the vertex's neighbourhood.

The per-cluster models (:class:`prt_torch.models.visibility.VisibilityModel`) map the whole subject's state to its
whole visibility. That needs training frames near every state played. A flapping cloth never comes close: on the
7.7k flag a held-out frame's nearest training frame is 8 cm RMS away, and its visibility predicts the held-out
frame worse than the training mean does. A local model learns visibility as a function of LOCAL shape instead, one
function for all vertices, so every vertex of every training frame is a sample (480 frames x 7.7k vertices on the
flag rather than 480 frames).

Conventions: ``V`` vertices, ``S`` neighbour samples per vertex, ``C = order^2`` SH coefficients, frames rows
``(t, b, n)`` (a world direction ``w`` has local coordinates ``F @ w``), visibility in the local frame like every
model of the package.

Per vertex ``i`` with rest position ``X_i`` and rest frame ``(t0, b0, n0)``:

* ``neighbours[i, s]`` (:func:`neighbour_pattern`): the rest vertex nearest to
  ``X_i + r_s (cos a_s t0 + sin a_s b0)``, rings of radii ``r`` times ``n`` angles (fixed at fit time);
* input ``x_i = (F_i (p_{neighbours[i, s]} - p_i))_s`` ``(3 S,)`` (:func:`local_offsets`, component-major): the
  neighbours' offsets in the vertex's POSED frame ``F_i``. Offsets in the vertex's own frame make the model exactly
  invariant under rigid motion of the subject (the frames of :class:`prt_torch.deform.frames.FrameOperator` rotate
  with it);
* ``linear``: ``v_i = m_i + x_i W``, one ``(3 S, C)`` matrix for all vertices and a per-vertex intercept ``m_i``;
* ``mlp``: ``v_i = m_i + W_L tanh(... tanh(x_i W_0 + c_i))``, where ``c_i (H,)`` is the vertex's rest
  neighbourhood (rest offsets and rest position) through the first layer, folded into one per-vertex term at fit
  time (:mod:`prt_torch.local.fit`): near a border or the pole the network knows where it is.

Input standardisation is folded into ``W`` / ``W_0`` and ``m`` / ``c`` after fitting, so the module holds only
what it runs.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch
from torch import nn

from prt_torch.errors import DamagedArtifact, PrtError, check
from prt_torch.shapes import check_shape

#: model kinds of the local family
LOCAL_KINDS = ("linear", "mlp")


def neighbour_pattern(rest: np.ndarray, rest_frames: np.ndarray, radii: list[float], n_angles: int) -> np.ndarray:
    """``(V, S)`` int64: for each vertex the rest vertex nearest (scipy k-d tree) to each point of a polar pattern
    in its rest tangent plane, ``S = len(radii) * n_angles``, radius-major.

    Args:
        rest: ``(V, 3)`` rest positions.
        rest_frames: ``(V, 3, 3)`` rest frames, rows ``(t0, b0, n0)``.
        radii: ring radii (world units).
        n_angles: samples per ring (angles ``2 pi k / n_angles`` from ``t0`` towards ``b0``).
    """
    from scipy.spatial import cKDTree

    x = np.asarray(rest, dtype=np.float64)
    f = np.asarray(rest_frames, dtype=np.float64)
    dims = check_shape(x, "V 3", name="rest positions")
    check_shape(f, "V 3 3", name="rest frames", dims=dims)
    check(len(radii) >= 1 and all(r > 0 for r in radii) and n_angles >= 1, "need radii > 0 and n_angles >= 1")
    a = 2 * np.pi * np.arange(n_angles) / n_angles
    r = np.asarray(radii, dtype=np.float64)
    # (R, A, 2) planar offsets -> (V, R*A, 3) world points
    plane = r[:, None, None] * np.stack([np.cos(a), np.sin(a)], axis=-1)[None]
    plane = plane.reshape(-1, 2)
    pts = x[:, None, :] + plane[None, :, 0, None] * f[:, None, 0] + plane[None, :, 1, None] * f[:, None, 1]
    _, idx = cKDTree(x).query(pts.reshape(-1, 3))
    return np.asarray(idx, dtype=np.int64).reshape(x.shape[0], -1)


def in_frame(offsets: torch.Tensor, frames: torch.Tensor) -> torch.Tensor:
    """``offsets (..., S, 3)`` world, ``frames (..., 3, 3)`` (rows t, b, n) -> ``(..., 3 S)``: the offsets in the
    frame, component-major (``S`` t-components, then ``S`` b-, then ``S`` n-components)."""
    loc = (offsets[..., None, :] * frames[..., None, :, :]).sum(-1)  # (..., S, 3): F @ offset
    return loc.transpose(-1, -2).flatten(-2)


def local_offsets(positions: torch.Tensor, frames: torch.Tensor, neighbours: torch.Tensor) -> torch.Tensor:
    """``positions (B, V, 3)``, ``frames (B, V, 3, 3)`` (rows t, b, n), ``neighbours (V, S)`` ->
    ``(B, V, 3 S)``: each neighbour's offset from the vertex in the vertex's frame (:func:`in_frame`)."""
    return in_frame(positions[:, neighbours] - positions[:, :, None], frames)


def sample_offsets(positions: torch.Tensor, frames: torch.Tensor, neighbours: torch.Tensor,
                   frame_idx: torch.Tensor, vertex_idx: torch.Tensor) -> torch.Tensor:
    """:func:`local_offsets` of single (frame, vertex) samples: ``positions (F, V, 3)``, ``frames (F, V, 3, 3)``,
    ``frame_idx``, ``vertex_idx (N,)`` -> ``(N, 3 S)`` (the training batches; the same rule)."""
    off = positions[frame_idx[:, None], neighbours[vertex_idx]] - positions[frame_idx, vertex_idx][:, None]
    return in_frame(off, frames[frame_idx, vertex_idx])


class LocalHead(nn.Module):
    """The network of a local model, vertex-last (the run-time graph; its input comes from the run-time twin
    :class:`prt_torch.local.soa.LocalOffsetsSoA` in the player): ``offsets (B, 3 S, V)`` -> ``(B, V, C)``.

    Args:
        kind: ``"linear"`` or ``"mlp"``.
        weights: ``[W_0 (3 S, H_0), ..., W_L (H, C)]``: one matrix for linear, the layers for mlp.
        biases: ``[c (V, H_0), b_1 (H_1), ..., b_{L-1}]`` for mlp (the first one per vertex); ``[]`` for linear.
        mean: ``(V, C)`` per-vertex intercept ``m``.
    """

    def __init__(self, kind: str, weights: list[Any], biases: list[Any], mean: Any) -> None:
        super().__init__()
        check(kind in LOCAL_KINDS, f"unknown local model kind {kind!r}; expected {', '.join(LOCAL_KINDS)}")
        self.kind = kind
        ws = [torch.as_tensor(np.asarray(w, np.float32)) for w in weights]
        bs = [torch.as_tensor(np.asarray(b, np.float32)) for b in biases]
        m = torch.as_tensor(np.asarray(mean, np.float32))
        check(kind == "linear" and len(ws) == 1 and not bs or kind == "mlp" and len(bs) == len(ws) - 1 >= 1,
              f"{kind} local model: {len(ws)} weights and {len(bs)} biases")
        check_shape(m, ("V", ws[-1].shape[1]), name="mean")
        for a, b in zip(ws[:-1], ws[1:], strict=True):
            check(a.shape[1] == b.shape[0], f"layer sizes do not chain: {tuple(a.shape)} then {tuple(b.shape)}")
        if bs:
            check(tuple(bs[0].shape) == (m.shape[0], ws[0].shape[1]),
                  f"per-vertex first bias must be ({m.shape[0]}, {ws[0].shape[1]}), got {tuple(bs[0].shape)}")
        # stored transposed for the vertex-last products W^T @ x
        for i, w in enumerate(ws):
            self.register_buffer(f"w{i}", w.T.contiguous())
        for i, b in enumerate(bs):
            self.register_buffer(f"b{i}", (b.T if i == 0 else b[:, None]).contiguous())
        self.register_buffer("mean", m)
        self.n_layers = len(ws)

    @property
    def n_inputs(self) -> int:
        return int(self.w0.shape[1])

    def forward(self, offsets: torch.Tensor) -> torch.Tensor:
        h = offsets
        for i in range(self.n_layers):
            h = getattr(self, f"w{i}") @ h  # (B, H_i, V)
            if i < self.n_layers - 1:
                h = torch.tanh(h + getattr(self, f"b{i}"))
        return h.transpose(1, 2) + self.mean


class LocalVisibility(nn.Module):
    """Local visibility model (module doc): ``positions (B, V, 3)``, ``frames (B, V, 3, 3)`` -> ``(B, V, C)``:
    :func:`local_offsets` through the :class:`LocalHead` (arguments as its, plus ``neighbours (V, S)`` from
    :func:`neighbour_pattern` and ``meta``: JSON-able settings kept with the model file)."""

    def __init__(self, kind: str, neighbours: Any, weights: list[Any], biases: list[Any], mean: Any,
                 meta: dict[str, Any] | None = None) -> None:
        super().__init__()
        nb = torch.as_tensor(np.asarray(neighbours), dtype=torch.int64)
        check_shape(nb, "V S", name="neighbours")
        self.head = LocalHead(kind, weights, biases, mean)
        check(self.head.n_inputs == 3 * nb.shape[1] and self.head.mean.shape[0] == nb.shape[0],
              f"local model: {self.head.n_inputs} inputs and {self.head.mean.shape[0]} vertices for neighbours "
              f"{tuple(nb.shape)}")
        self.register_buffer("neighbours", nb)
        self.meta = dict(meta or {})

    @property
    def kind(self) -> str:
        return self.head.kind

    @property
    def n_vertices(self) -> int:
        return int(self.neighbours.shape[0])

    @property
    def n_coeffs(self) -> int:
        return int(self.head.mean.shape[1])

    @property
    def n_samples(self) -> int:
        return int(self.neighbours.shape[1])

    def forward(self, positions: torch.Tensor, frames: torch.Tensor) -> torch.Tensor:
        return self.head(local_offsets(positions, frames, self.neighbours).transpose(1, 2))

    @torch.no_grad()
    def predict(self, positions: Any, frames: Any, batch: int = 8) -> np.ndarray:
        """numpy ``(F, V, 3)``, ``(F, V, 3, 3)`` -> ``(F, V, C)`` float32, ``batch`` frames at a time."""
        p = np.asarray(positions, np.float32)
        f = np.asarray(frames, np.float32)
        v = self.n_vertices
        if p.ndim != 3 or p.shape[1:] != (v, 3) or f.shape != (*p.shape[:2], 3, 3):
            raise PrtError(f"local model of {v} vertices needs positions (F, {v}, 3) and frames (F, {v}, 3, 3), "
                           f"got {p.shape} and {f.shape}")
        out = np.empty((p.shape[0], v, self.n_coeffs), np.float32)
        for s in range(0, p.shape[0], batch):
            out[s:s + batch] = self(torch.from_numpy(p[s:s + batch]), torch.from_numpy(f[s:s + batch])).numpy()
        return out

    def config(self) -> dict[str, Any]:
        return {"kind": self.kind, "n_layers": self.head.n_layers, "meta": self.meta}

    def arrays(self) -> dict[str, torch.Tensor]:
        """The constructor's arrays (weights un-transposed)."""
        h = self.head
        out = {"neighbours": self.neighbours.clone(), "mean": h.mean.clone()}
        for i in range(h.n_layers):
            out[f"w{i}"] = getattr(h, f"w{i}").T.contiguous()
        for i in range(h.n_layers - 1):
            b = getattr(h, f"b{i}")
            out[f"b{i}"] = (b.T if i == 0 else b[:, 0]).contiguous()
        return out


#: model file format of local models
LOCAL_FORMAT = "prt_torch.local/1"


def save_local(model: LocalVisibility, path: Any) -> None:
    """Write ``model`` atomically (torch ``.pt`` of tensors and a JSON-able config)."""
    from prt_torch.io import atomic_path

    with atomic_path(path) as tmp:
        torch.save({"format": LOCAL_FORMAT, "config": model.config(), "state_dict": model.arrays()}, tmp)


def load_local(path: Any) -> LocalVisibility:
    """Read a local model file (one-line :class:`PrtError` for a missing or foreign file)."""
    from prt_torch.models.visibility import read_payload

    payload = read_payload(path, (LOCAL_FORMAT,), "local model file")
    cfg, st = payload["config"], payload["state_dict"]
    n = int(cfg["n_layers"])
    try:
        return LocalVisibility(cfg["kind"], st["neighbours"], [st[f"w{i}"] for i in range(n)],
                               [st[f"b{i}"] for i in range(n - 1)], st["mean"], cfg.get("meta")).float().eval()
    except KeyError as exc:
        raise DamagedArtifact(f"{path}: local model file lacks {exc}") from None

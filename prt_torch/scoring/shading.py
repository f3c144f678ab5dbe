"""Shading on the shipping path: every visibility under every light, BRDF and lighting path at once.

Seed 003 eq. 11 through :func:`prt_torch.shade.shade_rpo` (torch, ``fused``), with
``L = tint * sum_b (w_b . y(wo)) (l . M_b v)`` in each vertex frame; ``wo`` is the unit direction from
the vertex to the player's camera, expressed in the frame (no clamp below the horizon: the exported
shading graph has none either). Vectorised over frames and vertices, chunked over frames
(:class:`ShippingShader`, at most ``max_rows`` vertex-frames per torch call). The lights and lighting
paths are :mod:`prt_torch.scoring.lighting`'s, the BRDFs :mod:`prt_torch.scoring.rpos`'s; frames are
orthonormalised once (:func:`orthonormal_frames`: polar factor, float64) and shared by both paths.
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from prt_torch.errors import check
from prt_torch.scoring.lighting import PATHS, local_lighting
from prt_torch.shapes import check_shape

if TYPE_CHECKING:
    from prt_torch.brdf.rpo import RPO
    from prt_torch.player.lighting import Lighting


def orthonormal_frames(frames: np.ndarray) -> np.ndarray:
    """``(..., 3, 3)`` -> float64 nearest rotations (polar factor ``U V^T`` of the SVD; det +1)."""
    f = np.asarray(frames, dtype=np.float64)
    check_shape(f, "... 3 3", name="frames")
    check(bool(np.isfinite(f).all()), "frames contain NaN or Inf")
    u, _, vt = np.linalg.svd(f)
    r = u @ vt
    flip = np.linalg.det(r) < 0  # not expected for right-handed frames; keep a proper rotation anyway
    if flip.any():
        u[flip, :, 2] *= -1
        r[flip] = u[flip] @ vt[flip]
    return r


Combo = tuple[str, str, str]  # (light, brdf, lighting path)


@dataclass
class ShippingShader:
    """Shades several visibilities at once on the shipping path (see the module docstring).

    Args:
        lights: ``{name: Lighting}`` (:func:`shipping_lights`).
        rpos: ``{name: RPO}`` (:func:`shipping_rpos`).
        eye: ``(3,)`` world camera position (the view directions point from each vertex to it).
        paths: lighting paths to evaluate (subset of :data:`PATHS`).
        dtype: torch dtype of the shading (float32 like the player; float64 for closed-form checks).
        max_rows: at most this many vertex-frames per torch call (memory bound; at least one frame).
    """

    lights: Mapping[str, Lighting]
    rpos: Mapping[str, RPO]
    eye: np.ndarray
    paths: Sequence[str] = PATHS
    dtype: Any = None
    max_rows: int = 1 << 16
    _rpo_t: dict[str, Any] = field(default_factory=dict, init=False, repr=False)

    def __post_init__(self) -> None:
        import torch

        from prt_torch.shade.rpo_shading import RPOTensors

        if self.dtype is None:
            self.dtype = torch.float32
        for p in self.paths:
            check(p in PATHS, f"unknown lighting path {p!r}: expected one of {list(PATHS)}")
        check(len(self.lights) > 0 and len(self.rpos) > 0, "shipping shader needs at least one light and one BRDF")
        self.eye = np.asarray(self.eye, dtype=np.float64).reshape(3)
        self._rpo_t = {n: RPOTensors.from_rpo(r, self.dtype) for n, r in self.rpos.items()}

    @property
    def combos(self) -> list[Combo]:
        """Every ``(light, brdf, path)`` this shader produces, in order."""
        return [(ln, bn, p) for ln in self.lights for bn in self.rpos for p in self.paths]

    def chunks(self, n_frames: int, n_vertices: int) -> list[slice]:
        """Frame slices of at most ``max_rows`` vertex-frames (at least one frame each)."""
        step = max(1, self.max_rows // max(n_vertices, 1))
        return [slice(i, min(i + step, n_frames)) for i in range(0, n_frames, step)]

    def shade_chunk(self, vis: Mapping[str, np.ndarray], frames: np.ndarray,
                    positions: np.ndarray) -> dict[Combo, dict[str, np.ndarray]]:
        """Radiance of every visibility under every combo for a few frames.

        Args:
            vis: ``{name: (f, V, C)}`` local-frame SH visibilities (a ``(C,)`` or ``(V, C)`` array broadcasts).
            frames: ``(f, V, 3, 3)`` vertex frames (rows t, b, n).
            positions: ``(f, V, 3)`` world positions.

        Returns:
            ``{(light, brdf, path): {name: (f, V, 3) float32}}``.
        """
        import torch

        from prt_torch.shade.rpo_shading import shade_rpo

        frames = np.asarray(frames)
        positions = np.asarray(positions, dtype=np.float64)
        check_shape(frames, "F V 3 3", name="frames")
        f, v = frames.shape[:2]
        check(positions.shape == (f, v, 3), f"positions: expected {(f, v, 3)}, got {positions.shape}")
        rot = orthonormal_frames(frames)  # (f, V, 3, 3) float64
        view = self.eye - positions
        view /= np.maximum(np.linalg.norm(view, axis=-1, keepdims=True), 1e-12)
        wo = np.einsum("fvij,fvj->fvi", rot, view)
        wo /= np.linalg.norm(wo, axis=-1, keepdims=True)
        dt = self.dtype
        rot_t = torch.as_tensor(rot.reshape(-1, 3, 3), dtype=dt)
        wo_t = torch.as_tensor(wo, dtype=dt)
        c = next(iter(self._rpo_t.values())).order ** 2
        vis_t = {}
        for name, a in vis.items():
            a = np.asarray(a, dtype=np.float32)
            check(a.shape[-1] == c, f"visibility {name!r}: expected {c} SH coefficients, got shape {a.shape}")
            vis_t[name] = torch.tensor(np.broadcast_to(a, (f, v, c)), dtype=dt)
        out: dict[Combo, dict[str, np.ndarray]] = {}
        with torch.no_grad():
            for ln, light in self.lights.items():
                for p in self.paths:
                    l_local = local_lighting(light, rot_t, p).reshape(f, v, c, 3)
                    for bn, rpo in self._rpo_t.items():
                        out[(ln, bn, p)] = {name: shade_rpo(x, l_local, wo_t, rpo, check=False).numpy()
                                            .astype(np.float32, copy=False) for name, x in vis_t.items()}
        return out

    def shade(self, vis: Mapping[str, np.ndarray], frames: np.ndarray,
              positions: np.ndarray) -> Iterator[tuple[slice, dict[Combo, dict[str, np.ndarray]]]]:
        """:meth:`shade_chunk` over frame chunks: yields ``(frame slice, results)`` (``vis`` arrays ``(F, V, C)``,
        or broadcastable ``(C,)``/``(V, C)``; ``frames (F, V, 3, 3)``; ``positions (F, V, 3)``)."""
        f, v = np.asarray(frames).shape[:2]
        for sl in self.chunks(f, v):
            sub = {k: (a[sl] if np.ndim(a) == 3 else a) for k, a in vis.items()}
            yield sl, self.shade_chunk(sub, frames[sl], positions[sl])

    def shade_all(self, vis: Mapping[str, np.ndarray], frames: np.ndarray,
                  positions: np.ndarray) -> dict[Combo, dict[str, np.ndarray]]:
        """Every chunk of :meth:`shade` concatenated: ``{combo: {name: (F, V, 3)}}`` (small inputs only)."""
        parts: dict[Combo, dict[str, list[np.ndarray]]] = {}
        for _, res in self.shade(vis, frames, positions):
            for combo, d in res.items():
                for name, a in d.items():
                    parts.setdefault(combo, {}).setdefault(name, []).append(a)
        return {combo: {n: np.concatenate(a) for n, a in d.items()} for combo, d in parts.items()}

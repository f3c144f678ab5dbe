"""MERL measured BRDFs (Matusik et al. 2003, ``.binary``): reader, lookup, and a writer for tests.

File format (little-endian): three int32 dimensions ``(90, 90, 180)`` = ``(theta_h, theta_d, phi_d)``
bins, then ``3 * N`` float64 values (``N = 90 * 90 * 180``): the R block, the G block, the B block.
Stored values are multiplied by the channel scales ``(1/1500, 1.15/1500, 1.66/1500)``; negative values
mark missing samples (read as 0).

Lookup (the reference ``BRDFRead.cpp``), from local ``(wi, wo)`` with z = normal: ``h = (wi + wo)/|.|``,
``theta_h = acos(h.z)``, ``phi_h = atan2(h.y, h.x)``; the difference vector is ``wi`` rotated by
``-phi_h`` about the normal and by ``-theta_h`` about the binormal, with polar angles
``(theta_d, phi_d)``; ``phi_d < 0`` is folded by ``+pi`` (reciprocity). Indices:
``i_h = floor(sqrt(theta_h / (pi/2) * 90 * 90))``, ``i_d = floor(theta_d / (pi/2) * 90)``,
``i_p = floor(phi_d / pi * 180)``, each clamped to its range; flat index ``i_p + 180 (i_d + 90 i_h)``.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from prt_torch.brdf.analytic import BRDF, check_pair
from prt_torch.errors import PrtError
from prt_torch.io import atomic_write_bytes

MERL_DIMS = (90, 90, 180)
MERL_SCALES = np.array([1.0 / 1500, 1.15 / 1500, 1.66 / 1500])
_N = MERL_DIMS[0] * MERL_DIMS[1] * MERL_DIMS[2]


def _rot(v: np.ndarray, axis: np.ndarray, angle: np.ndarray) -> np.ndarray:
    """Rodrigues rotation of ``v (N, 3)`` about the unit ``axis (3,)`` by ``angle (N,)``."""
    c, s = np.cos(angle)[:, None], np.sin(angle)[:, None]
    return v * c + np.cross(axis, v) * s + axis[None, :] * (v @ axis)[:, None] * (1 - c)


def half_diff_angles(wi: np.ndarray, wo: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Rusinkiewicz half/difference angles ``(theta_h, theta_d, phi_d)`` of ``(N, 3)`` local pairs."""
    h = wi + wo
    h = h / np.linalg.norm(h, axis=1, keepdims=True)
    theta_h = np.arccos(np.clip(h[:, 2], -1.0, 1.0))
    phi_h = np.arctan2(h[:, 1], h[:, 0])
    d = _rot(wi, np.array([0.0, 0.0, 1.0]), -phi_h)
    d = _rot(d, np.array([0.0, 1.0, 0.0]), -theta_h)
    theta_d = np.arccos(np.clip(d[:, 2], -1.0, 1.0))
    phi_d = np.arctan2(d[:, 1], d[:, 0])
    return theta_h, theta_d, phi_d


def merl_index(theta_h: np.ndarray, theta_d: np.ndarray, phi_d: np.ndarray) -> np.ndarray:
    """Flat table index of half/difference angles (the reference lookup, vectorised), ``(N,)`` int64."""
    th_deg = np.maximum(theta_h, 0.0) / (math.pi / 2) * 90.0
    ih = np.clip(np.floor(np.sqrt(th_deg * 90.0)), 0, 89).astype(np.int64)
    ih = np.where(theta_h <= 0, 0, ih)
    idd = np.clip(np.floor(theta_d / (math.pi / 2) * 90.0), 0, 89).astype(np.int64)
    p = np.where(phi_d < 0, phi_d + math.pi, phi_d)
    ip = np.clip(np.floor(p / math.pi * 180.0), 0, 179).astype(np.int64)
    return ip + 180 * (idd + 90 * ih)


def read_merl(path: str | os.PathLike[str]) -> np.ndarray:
    """Read a MERL ``.binary`` file; returns the scaled table ``(3, 90*90*180)`` float64 (negatives -> 0)."""
    p = Path(path)
    if not p.is_file():
        raise PrtError(f"MERL BRDF file not found: {p}")
    raw = p.read_bytes()
    if len(raw) < 12:
        raise PrtError(f"{p.name}: not a MERL BRDF file (too short)")
    dims = tuple(int(x) for x in np.frombuffer(raw[:12], dtype="<i4"))
    if dims != MERL_DIMS:
        raise PrtError(f"{p.name}: not a MERL BRDF file (dimensions {dims}, expected {MERL_DIMS})")
    need = 12 + 3 * _N * 8
    if len(raw) != need:
        raise PrtError(f"{p.name}: MERL BRDF file has {len(raw)} bytes, expected {need}")
    vals = np.frombuffer(raw[12:], dtype="<f8").reshape(3, _N)
    if not np.isfinite(vals).all():
        raise PrtError(f"{p.name}: MERL BRDF contains NaN or Inf")
    return np.maximum(vals, 0.0) * MERL_SCALES[:, None]


def write_merl(path: str | os.PathLike[str], brdf: BRDF) -> None:
    """Sample ``brdf`` (RGB ``__call__``) at the MERL bin centres and write a ``.binary`` file atomically.

    Bin centres: ``theta_h = ((i_h + 0.5)/90)^2 pi/2``, ``theta_d = (i_d + 0.5)/90 pi/2``,
    ``phi_d = (i_p + 0.5)/180 pi``; ``wi`` is the difference vector rotated by ``theta_h`` about y,
    ``wo`` its mirror about ``h``. Pairs below the horizon store 0.
    """
    ih, idd, ip = np.meshgrid(np.arange(90), np.arange(90), np.arange(180), indexing="ij")
    th = ((ih.ravel() + 0.5) / 90) ** 2 * (math.pi / 2)
    td = (idd.ravel() + 0.5) / 90 * (math.pi / 2)
    pd = (ip.ravel() + 0.5) / 180 * math.pi
    d = np.stack([np.sin(td) * np.cos(pd), np.sin(td) * np.sin(pd), np.cos(td)], -1)
    wi = _rot(d, np.array([0.0, 1.0, 0.0]), th)
    h = np.stack([np.sin(th), np.zeros_like(th), np.cos(th)], -1)
    wo = 2 * (wi * h).sum(1, keepdims=True) * h - wi
    wi /= np.linalg.norm(wi, axis=1, keepdims=True)
    wo /= np.linalg.norm(wo, axis=1, keepdims=True)
    rgb = brdf(wi, wo)  # (N, 3), zero below the horizon
    body = (rgb.T / MERL_SCALES[:, None]).astype("<f8").tobytes()
    atomic_write_bytes(path, np.array(MERL_DIMS, dtype="<i4").tobytes() + body)


@dataclass
class MerlBRDF(BRDF):
    """A measured MERL BRDF. ``__call__`` returns the measured RGB; :meth:`shape` is the channel mean
    (what an RPO factors) and ``tint`` the channel ratios of the normal-incidence albedos, so
    ``tint * shape`` approximates the RGB data (the chroma variation over angles is not kept)."""

    table: np.ndarray = field(default_factory=lambda: np.zeros((3, _N)), repr=False)
    name: str = "merl"

    @classmethod
    def load(cls, path: str | os.PathLike[str], name: str | None = None) -> MerlBRDF:
        """Read a ``.binary`` file; the tint is computed from the data."""
        table = read_merl(path)
        out = cls(tint=np.ones(3), table=table, name=name or Path(path).stem)
        out.tint = out.albedo_tint()
        return out

    def rgb(self, wi: np.ndarray, wo: np.ndarray) -> np.ndarray:
        """Measured RGB ``(N, 3)``; 0 where either direction is below the horizon."""
        wi, wo = check_pair(wi, wo)
        up = (wi[:, 2] > 0) & (wo[:, 2] > 0)
        out = np.zeros((len(wi), 3))
        if up.any():
            idx = merl_index(*half_diff_angles(wi[up], wo[up]))
            out[up] = self.table[:, idx].T
        return out

    def __call__(self, wi: np.ndarray, wo: np.ndarray) -> np.ndarray:
        return self.rgb(wi, wo)

    def _shape(self, wi: np.ndarray, wo: np.ndarray) -> np.ndarray:
        return self.table[:, merl_index(*half_diff_angles(wi, wo))].mean(0)

    def albedo_tint(self, n: int = 4096) -> np.ndarray:
        """Per-channel normal-incidence albedo divided by the mean channel's, ``(3,)``."""
        from prt_torch.brdf.factor import hemisphere_rule

        dirs, w = hemisphere_rule(32, 64)
        wo = np.broadcast_to(np.array([0.0, 0.0, 1.0]), dirs.shape).copy()
        rgb = (self.rgb(dirs, wo) * (dirs[:, 2] * w)[:, None]).sum(0)
        m = rgb.mean()
        return rgb / m if m > 0 else np.ones(3)

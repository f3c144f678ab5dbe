"""A set of spherical Gaussian (SG) lobes with RGB amplitudes, in torch.

``G_k(v) = mu_k exp(lambda_k (v . p_k - 1))`` (seed 004, eq. 3) with

* ``axis`` ``p`` : ``(K, 3)`` unit vectors (world frame z up, or a local frame - the caller's choice),
* ``sharpness`` ``lambda`` : ``(K,)`` > 0 (bandwidth; larger = narrower),
* ``amplitude`` ``mu`` : ``(K, 3)`` RGB (radiance for lighting lobes, BRDF x cosine for material lobes).

The function represented is the SUM over the ``K`` lobes. Float32 or float64, any device. Construction
validates shapes, finiteness, unit axes and ``lambda > 0`` and raises a one-line :class:`PrtError`.
Amplitudes may be negative (a residual scale of a multiscale fit may be signed).

Files: ``.json`` (``{"axis": [[x, y, z], ...], "sharpness": [...], "amplitude": [[r, g, b], ...]}``) or
``.npz`` (arrays ``axis``, ``sharpness``, ``amplitude``), written atomically.
"""

from __future__ import annotations

import io
import json
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch

from prt_torch.errors import PrtError, check
from prt_torch.io import atomic_write_bytes, atomic_write_json
from prt_torch.shapes import check_shape

#: tolerance on ``|axis| = 1``
_UNIT_TOL = 1e-3


def _as_tensor(x: Any, name: str, dtype: torch.dtype | None = None,
               device: torch.device | str | None = None) -> torch.Tensor:
    if isinstance(x, torch.Tensor):
        t = x
    else:
        try:
            t = torch.as_tensor(np.asarray(x, dtype=np.float64))
        except (TypeError, ValueError) as exc:
            raise PrtError(f"SG {name} must be numeric, got {type(x).__name__}: {exc}") from None
    check(t.is_floating_point(), f"SG {name} must be a floating-point tensor, got {t.dtype}")
    if dtype is not None or device is not None:
        t = t.to(dtype=dtype or t.dtype, device=device or t.device)
    return t


@dataclass
class SGLobes:
    """``K`` spherical Gaussians ``mu exp(lambda (v . p - 1))``; the represented function is their sum.

    Attributes:
        axis: ``(K, 3)`` unit lobe axes ``p``.
        sharpness: ``(K,)`` bandwidths ``lambda > 0``.
        amplitude: ``(K, 3)`` RGB amplitudes ``mu``.
    """

    axis: torch.Tensor
    sharpness: torch.Tensor
    amplitude: torch.Tensor

    def __post_init__(self) -> None:
        self.axis = _as_tensor(self.axis, "axis")
        dtype, device = self.axis.dtype, self.axis.device
        self.sharpness = _as_tensor(self.sharpness, "sharpness", dtype, device)
        self.amplitude = _as_tensor(self.amplitude, "amplitude", dtype, device)
        dims = check_shape(self.axis, "K 3", name="SG axis")
        check_shape(self.sharpness, "K", name="SG sharpness", dims=dims)
        check_shape(self.amplitude, "K 3", name="SG amplitude", dims=dims)
        k = dims["K"]
        for name, t in (("axis", self.axis), ("sharpness", self.sharpness), ("amplitude", self.amplitude)):
            if not bool(torch.isfinite(t).all()):
                raise PrtError(f"SG {name} contains NaN or Inf ({int((~torch.isfinite(t)).sum())} value(s))")
        if k and not bool((self.sharpness > 0).all()):
            raise PrtError(f"SG sharpness (lambda) must be > 0, got min {float(self.sharpness.min()):.6g}")
        if k:
            err = float((self.axis.norm(dim=1) - 1).abs().max())
            check(err <= _UNIT_TOL, f"SG axes must be unit vectors, got |axis| off by {err:.3g}")

    # ------------------------------------------------------------------------------------------ basics

    def __len__(self) -> int:
        return int(self.axis.shape[0])

    @property
    def dtype(self) -> torch.dtype:
        return self.axis.dtype

    @property
    def device(self) -> torch.device:
        return self.axis.device

    def to(self, dtype: torch.dtype | None = None, device: torch.device | str | None = None) -> SGLobes:
        """A copy in ``dtype`` on ``device`` (either may be None: unchanged)."""
        kw: dict[str, Any] = {"dtype": dtype or self.dtype, "device": device or self.device}
        return SGLobes(self.axis.to(**kw), self.sharpness.to(**kw), self.amplitude.to(**kw))

    def as_tuple(self) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """``(axis (K, 3), sharpness (K,), amplitude (K, 3))`` for the functions of :mod:`prt_torch.sg.algebra`."""
        return self.axis, self.sharpness, self.amplitude

    def __getitem__(self, idx: Any) -> SGLobes:
        """A subset of the lobes (``idx``: slice, index tensor or boolean mask over ``K``)."""
        if isinstance(idx, int):
            idx = slice(idx, idx + 1 if idx != -1 else None)
        return SGLobes(self.axis[idx], self.sharpness[idx], self.amplitude[idx])

    @staticmethod
    def cat(parts: list[SGLobes] | tuple[SGLobes, ...]) -> SGLobes:
        """Concatenate lobe sets (dtype/device of the first)."""
        check(len(parts) > 0, "SGLobes.cat needs at least one lobe set")
        for p in parts:
            check(isinstance(p, SGLobes), f"SGLobes.cat expects SGLobes, got {type(p).__name__}")
        d, dev = parts[0].dtype, parts[0].device
        return SGLobes(torch.cat([p.axis.to(dtype=d, device=dev) for p in parts]),
                       torch.cat([p.sharpness.to(dtype=d, device=dev) for p in parts]),
                       torch.cat([p.amplitude.to(dtype=d, device=dev) for p in parts]))

    @staticmethod
    def empty(dtype: torch.dtype = torch.float64, device: torch.device | str = "cpu") -> SGLobes:
        """No lobes (the zero function)."""
        z = torch.zeros(0, 3, dtype=dtype, device=device)
        return SGLobes(z, torch.zeros(0, dtype=dtype, device=device), z.clone())

    # ------------------------------------------------------------------------------------------ maths

    def eval(self, dirs: torch.Tensor) -> torch.Tensor:
        """Sum of the lobes at unit directions ``dirs (N, 3)`` -> ``(N, 3)`` RGB."""
        from prt_torch.sg.algebra import sg_eval

        return sg_eval(self.axis, self.sharpness, self.amplitude, dirs)

    def integral(self) -> torch.Tensor:
        """Integral of the sum over the sphere, ``(3,)`` RGB."""
        from prt_torch.sg.algebra import sg_integral

        return sg_integral(self.sharpness, self.amplitude).sum(0)

    def rotated(self, rotation: torch.Tensor) -> SGLobes:
        """Lobes rotated by the ``(3, 3)`` matrix ``R`` (axes ``p -> R p``)."""
        r = _as_tensor(rotation, "rotation", self.dtype, self.device)
        check_shape(r, "3 3", name="SG rotation")
        return SGLobes(self.axis @ r.T, self.sharpness, self.amplitude)

    # ------------------------------------------------------------------------------------------ files

    def to_dict(self) -> dict[str, list]:
        """``{"axis": (K, 3), "sharpness": (K,), "amplitude": (K, 3)}`` as nested lists (float64)."""
        return {"axis": self.axis.double().cpu().tolist(), "sharpness": self.sharpness.double().cpu().tolist(),
                "amplitude": self.amplitude.double().cpu().tolist()}

    @staticmethod
    def from_dict(d: dict[str, Any], dtype: torch.dtype = torch.float64) -> SGLobes:
        """Inverse of :meth:`to_dict` (validates)."""
        check(isinstance(d, dict), f"SG lobes must be a mapping, got {type(d).__name__}")
        missing = [k for k in ("axis", "sharpness", "amplitude") if k not in d]
        check(not missing, f"SG lobes lack {', '.join(missing)}")
        def arr(name: str, shape: tuple[int, ...]) -> torch.Tensor:
            try:
                a = np.asarray(d[name], dtype=np.float64)
            except (TypeError, ValueError):
                raise PrtError(f"SG lobes {name} must be numeric (nested lists)") from None
            return torch.as_tensor(a.reshape(shape) if a.size == 0 else a, dtype=dtype)

        return SGLobes(arr("axis", (0, 3)), arr("sharpness", (0,)), arr("amplitude", (0, 3)))

    def save(self, path: str | os.PathLike[str]) -> None:
        """Write ``.json`` or ``.npz`` (by suffix), atomically."""
        p = Path(path)
        if p.suffix == ".json":
            atomic_write_json(p, self.to_dict())
        elif p.suffix == ".npz":
            buf = io.BytesIO()
            np.savez(buf, axis=self.axis.double().cpu().numpy(), sharpness=self.sharpness.double().cpu().numpy(),
                     amplitude=self.amplitude.double().cpu().numpy())
            atomic_write_bytes(p, buf.getvalue())
        else:
            raise PrtError(f"SG lobes file must end in .json or .npz, got {p.name}")

    @staticmethod
    def load(path: str | os.PathLike[str], dtype: torch.dtype = torch.float64) -> SGLobes:
        """Read a file written by :meth:`save` (validates; one-line errors for missing/malformed files)."""
        p = Path(path)
        check(p.is_file(), f"SG lobes file not found: {p}")
        if p.suffix == ".json":
            try:
                d = json.loads(p.read_text())
            except (json.JSONDecodeError, UnicodeDecodeError) as exc:
                raise PrtError(f"SG lobes file {p.name} is not valid JSON: {str(exc).splitlines()[0]}") from None
            return SGLobes.from_dict(d, dtype)
        if p.suffix == ".npz":
            try:
                with np.load(p) as z:
                    d = {k: z[k] for k in ("axis", "sharpness", "amplitude") if k in z}
            except (OSError, ValueError) as exc:
                raise PrtError(f"SG lobes file {p.name} is not a valid .npz: {str(exc).splitlines()[0]}") from None
            missing = [k for k in ("axis", "sharpness", "amplitude") if k not in d]
            check(not missing, f"SG lobes file {p.name} lacks {', '.join(missing)}")
            return SGLobes(*(torch.as_tensor(d[k], dtype=dtype) for k in ("axis", "sharpness", "amplitude")))
        raise PrtError(f"SG lobes file must end in .json or .npz, got {p.name}")

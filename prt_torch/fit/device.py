"""Where the fit runs: the ``train.device`` setting and array placement for the device-generic fit code.

``train.device`` is ``auto`` (CUDA when ``torch.cuda.is_available()``, else the CPU), ``cpu`` or ``cuda``.
The CPU runs the reference path: numpy (LAPACK) ridge and numpy's SIMD tanh inside the MLP objective,
float64, bit-identical to the fit before devices existed (so the ``train`` stage key of a CPU fit is
unchanged). Any other device runs the same formulas on torch tensors on that device, still float64:
the data is moved there once per fit, every buffer is allocated there, and the fitted parameters come
back to the CPU (saved models load anywhere). Passing ``torch.device("cpu")`` explicitly to the fit
functions runs that torch path on the CPU (how the tests exercise it without a GPU); ``None`` is the
reference path.

The ridge code is written once for both array kinds (numpy arrays -> numpy, tensors -> tensors on their
device); the helpers below are the few operations whose spelling differs between the two.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
import torch

from prt_torch.errors import PrtError

#: the values of ``train.device``
DEVICES: tuple[str, ...] = ("auto", "cpu", "cuda")

Array = np.ndarray | torch.Tensor


def resolve_device(name: str) -> str:
    """``auto`` -> ``cuda`` when torch sees a GPU, else ``cpu``; ``cpu``/``cuda`` as given (``cuda`` without a
    GPU: one-line :class:`PrtError`)."""
    if name not in DEVICES:
        raise PrtError(f"unknown fit device {str(name)[:32]!r}: expected one of {', '.join(DEVICES)}")
    if name == "auto":
        return "cuda" if torch.cuda.is_available() else "cpu"
    if name == "cuda" and not torch.cuda.is_available():
        raise PrtError("train.device is cuda but torch sees no CUDA GPU (use device: auto or cpu)")
    return name


def fit_device(name: str) -> torch.device | None:
    """The device argument of the fit functions for ``train.device = name``: None (the CPU reference path)
    or a CUDA ``torch.device``."""
    dev = resolve_device(name)
    return None if dev == "cpu" else torch.device(dev)


def like(a: Any, ref: Array) -> Array:
    """``a`` (array or tensor; dtype kept) as the kind of ``ref``: a tensor on ``ref``'s device, or numpy."""
    if isinstance(ref, torch.Tensor):
        return torch.as_tensor(a, device=ref.device)
    return a.cpu().numpy() if isinstance(a, torch.Tensor) else np.asarray(a)


def zeros(shape: tuple[int, ...], ref: Array) -> Array:
    """float64 zeros of ``shape`` of the kind (and device) of ``ref``."""
    if isinstance(ref, torch.Tensor):
        return torch.zeros(shape, dtype=torch.float64, device=ref.device)
    return np.zeros(shape)


def concat(parts: Sequence[Array], axis: int) -> Array:
    """``np.concatenate`` / ``torch.cat`` along ``axis``."""
    return torch.cat(list(parts), dim=axis) if isinstance(parts[0], torch.Tensor) else np.concatenate(parts, axis=axis)


def stack(parts: Sequence[Array]) -> Array:
    """``np.stack`` / ``torch.stack`` along a new first axis."""
    return torch.stack(list(parts)) if isinstance(parts[0], torch.Tensor) else np.stack(parts)


def permute(a: Array, axes: tuple[int, ...]) -> Array:
    """``np.transpose(a, axes)`` / ``a.permute(axes)``."""
    return a.permute(axes) if isinstance(a, torch.Tensor) else np.transpose(a, axes)


def host(a: Array) -> np.ndarray:
    """numpy on the CPU (a numpy array is returned as it is)."""
    return a.detach().cpu().numpy() if isinstance(a, torch.Tensor) else a

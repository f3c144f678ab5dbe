"""Linear radiance -> display colours: exposure, a soft shoulder, sRGB-like gamma (numpy)."""

from __future__ import annotations

import numpy as np

from prt_torch.errors import PrtError

GAMMA = 2.2


def auto_exposure(radiance: np.ndarray, percentile: float = 95.0, target: float = 0.9) -> float:
    """Exposure that maps the ``percentile`` of the per-vertex max channel to ``target``."""
    r = np.asarray(radiance, dtype=np.float32)
    if r.shape[-1] != 3 or not np.isfinite(r).all():
        raise PrtError(f"radiance must be finite (..., 3), got shape {r.shape}")
    p = float(np.percentile(r.max(axis=-1), percentile))
    return target / p if p > 1e-12 else 1.0


def to_colors(radiance: np.ndarray, exposure: float, gamma: float = GAMMA) -> np.ndarray:
    """``(..., 3)`` linear radiance -> ``(..., 3)`` uint8: ``x = exposure * L``, clipped to [0, 1],
    then ``x ** (1 / gamma)``."""
    x = np.clip(np.asarray(radiance, dtype=np.float32) * np.float32(exposure), 0.0, 1.0)
    return (np.power(x, np.float32(1.0 / gamma)) * 255.0 + 0.5).astype(np.uint8)

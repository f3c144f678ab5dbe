"""Linear radiance -> display colours: exposure, Reinhard's extended tone curve, gamma (numpy).

``x = exposure * L``; ``y = x (1 + x / white^2) / (1 + x)`` (Reinhard et al. 2002, eq. 4: maps
``white`` to 1 and compresses highlights smoothly instead of clipping them); colour
``= clip(y, 0, 1) ** (1 / gamma)``. Negative radiance (SH ringing) clips to black.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from prt_torch.errors import PrtError

GAMMA = 2.2


@dataclass(frozen=True)
class ToneMap:
    """``exposure`` scales radiance; ``white`` is the exposed value shown as pure white."""

    exposure: float
    white: float

    def __call__(self, radiance: np.ndarray) -> np.ndarray:
        return to_colors(radiance, self.exposure, self.white)


def auto_tonemap(radiance: np.ndarray, middle: float = 0.3, white_percentile: float = 99.5) -> ToneMap:
    """A tone map that puts the median per-vertex max channel at ``middle`` and its
    ``white_percentile`` at white."""
    r = np.asarray(radiance, dtype=np.float32)
    if r.ndim < 1 or r.shape[-1] != 3 or not np.isfinite(r).all():
        raise PrtError(f"radiance must be finite (..., 3), got shape {r.shape}")
    m = r.max(axis=-1)
    med = float(np.median(m))
    exposure = middle / med if med > 1e-12 else 1.0
    white = max(float(np.percentile(m, white_percentile)) * exposure, 1.0)
    return ToneMap(exposure, white)


def to_colors(radiance: np.ndarray, exposure: float, white: float | None = None, gamma: float = GAMMA) -> np.ndarray:
    """``(..., 3)`` linear radiance -> ``(..., 3)`` uint8 (see module docstring; ``white=None``: plain clip)."""
    x = np.maximum(np.asarray(radiance, dtype=np.float32) * np.float32(exposure), 0.0)
    if white is not None:
        x = x * (1.0 + x / np.float32(white * white)) / (1.0 + x)
    x = np.minimum(x, 1.0)
    return (np.power(x, np.float32(1.0 / gamma)) * 255.0 + 0.5).astype(np.uint8)

"""Error statistics of scored radiance and images, pooled over every entry seen (PSNR by :mod:`prt_torch.metrics`).

Image PSNR (:func:`image_psnr`) is ``10 log10(1 / MSE)`` over the colours in ``[0, 1]`` (the rendered 8-bit
image / 255) of the character's pixels only (the mask of :meth:`prt_torch.scoring.images.ImageRenderer.mask`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from prt_torch.errors import check
from prt_torch.metrics import psnr_from_mse


@dataclass
class RadianceStats:
    """Streaming vertex-radiance errors of a prediction vs a truth (sums over every entry seen).

    ``radiance_rel_rmse = sqrt(sum (p - t)^2 / sum t^2)`` (:func:`prt_torch.metrics.rel_rmse`) and
    ``psnr_vertex = 10 log10(max(t)^2 / mean (p - t)^2)`` (:func:`prt_torch.metrics.psnr`).
    """

    sse: float = 0.0
    sst: float = 0.0
    n: int = 0
    peak: float = 0.0

    def add(self, pred: np.ndarray, truth: np.ndarray) -> None:
        p, t = np.asarray(pred, dtype=np.float64), np.asarray(truth, dtype=np.float64)
        check(p.shape == t.shape, f"radiance: prediction {p.shape} and truth {t.shape} differ in shape")
        self.sse += float(((p - t) ** 2).sum())
        self.sst += float((t * t).sum())
        self.n += int(t.size)
        self.peak = max(self.peak, float(t.max()) if t.size else 0.0)

    @property
    def rel_rmse(self) -> float:
        return float(np.sqrt(self.sse / max(self.sst, 1e-30)))

    @property
    def psnr(self) -> float:
        return psnr_from_mse(self.sse / max(self.n, 1), self.peak)


@dataclass
class ImageStats:
    """Pooled image error over masked pixels: ``sse`` over colours in [0, 1], ``n`` masked channel values."""

    sse: float = 0.0
    n: int = 0

    def add(self, sse: float, n: int) -> None:
        self.sse += float(sse)
        self.n += int(n)

    @property
    def psnr(self) -> float | None:
        if self.n == 0:
            return None
        return psnr_from_mse(self.sse / self.n)


def image_sse(a: np.ndarray, b: np.ndarray, mask: np.ndarray) -> tuple[float, int]:
    """Sum of squared differences of two ``(H, W, 3)`` uint8 images as colours in [0, 1] over ``mask (H, W)``,
    and the number of channel values summed."""
    check(a.shape == b.shape and a.shape[:2] == mask.shape, f"images {a.shape}, {b.shape} and mask {mask.shape}")
    d = (a[mask].astype(np.float64) - b[mask].astype(np.float64)) / 255.0
    return float((d * d).sum()), int(d.size)


def image_psnr(a: np.ndarray, b: np.ndarray, mask: np.ndarray) -> float:
    """PSNR (dB, peak 1.0) of ``(H, W, 3)`` uint8 images ``a`` vs ``b`` over the pixels of ``mask``."""
    sse, n = image_sse(a, b, mask)
    check(n > 0, "image PSNR: the mask is empty (the character is not in view)")
    return psnr_from_mse(sse / n)

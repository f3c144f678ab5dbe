"""Labelled image strips and difference images of the reports (``prt eval``, ``prt compare``, scripts)."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from prt_torch.errors import check


def image_strip(images: Sequence[np.ndarray], labels: Sequence[str], diffs: Sequence[np.ndarray | None] = (),
                diff_labels: Sequence[str] = (), scale: float = 4.0) -> np.ndarray:
    """A labelled strip: row 1 ``images``; row 2 (when ``diffs`` is given) ``scale x |diff - ref|`` images as
    uint8 (``None`` entries are left black). ``diffs`` entries are ``(img, ref)``-difference images already
    computed by :func:`abs_diff_image`."""
    import cv2

    def lab(img: np.ndarray, text: str) -> np.ndarray:
        img = np.ascontiguousarray(img.copy())
        cv2.putText(img, text, (10, 24), cv2.FONT_HERSHEY_SIMPLEX, 0.6, (240, 240, 240), 2, cv2.LINE_AA)
        return img

    check(len(images) == len(labels) and len(images) > 0, "image strip: need one label per image")
    row1 = np.concatenate([lab(i, t) for i, t in zip(images, labels, strict=True)], axis=1)
    if not diffs:
        return row1
    blank = np.zeros_like(images[0])
    row2 = np.concatenate([lab(blank if d is None else d, t) for d, t in zip(diffs, diff_labels, strict=True)], axis=1)
    return np.concatenate([row1, row2], axis=0)


def abs_diff_image(img: np.ndarray, ref: np.ndarray, scale: float = 4.0) -> np.ndarray:
    """``scale x |img - ref|`` of two uint8 images, clipped to uint8."""
    d = np.abs(img.astype(np.float32) - ref.astype(np.float32)) * scale
    return np.clip(d + 0.5, 0, 255).astype(np.uint8)


def write_png(path: Path, image: np.ndarray) -> Path:
    """Write an ``(H, W, 3)`` uint8 RGB image atomically (the player's PNG writer)."""
    from prt_torch.player.video import write_png as _write

    _write(Path(path), image)
    return Path(path)

"""Writing frames: PNG sequences and MP4 (imageio + imageio-ffmpeg, libx264), atomically."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from prt_torch.errors import PrtError
from prt_torch.io import atomic_path


def write_png(path: str | os.PathLike[str], image: np.ndarray) -> Path:
    """Write an ``(H, W, 3)`` uint8 image as PNG atomically."""
    import imageio.v2 as iio

    image = np.asarray(image)
    if image.ndim != 3 or image.shape[2] not in (3, 4) or image.dtype != np.uint8:
        raise PrtError(f"PNG image must be (H, W, 3|4) uint8, got {image.shape} {image.dtype}")
    path = Path(path)
    with atomic_path(path) as tmp:
        iio.imwrite(tmp, image, format="png")
    return path


class VideoWriter:
    """Streams frames to an MP4 (libx264) written to a temporary file, renamed on :meth:`close`.

    Frame sizes are padded to even width/height (a libx264 requirement) by edge replication.
    """

    def __init__(self, path: str | os.PathLike[str], fps: float = 30.0, quality: int = 7) -> None:
        import imageio.v2 as iio

        self.path = Path(path)
        if self.path.suffix.lower() not in (".mp4", ".m4v", ".mov", ".mkv"):
            raise PrtError(f"unsupported video format {self.path.suffix!r}: use .mp4")
        self._ctx = atomic_path(self.path)
        self._tmp = self._ctx.__enter__()
        self._writer = iio.get_writer(self._tmp, format="FFMPEG", mode="I", fps=float(fps), codec="libx264",
                                      quality=quality, pixelformat="yuv420p", macro_block_size=1)
        self.frames = 0

    def append(self, image: np.ndarray) -> None:
        h, w = image.shape[:2]
        if h % 2 or w % 2:
            image = np.pad(image, ((0, h % 2), (0, w % 2), (0, 0)), mode="edge")
        self._writer.append_data(np.ascontiguousarray(image[..., :3]))
        self.frames += 1

    def close(self) -> Path:
        self._writer.close()
        self._ctx.__exit__(None, None, None)
        return self.path

    def abort(self) -> None:
        try:
            self._writer.close()
        finally:
            import contextlib

            with contextlib.suppress(Exception):
                self._ctx.__exit__(RuntimeError, RuntimeError("aborted"), None)

    def __enter__(self) -> VideoWriter:
        return self

    def __exit__(self, exc_type: object, exc: object, tb: object) -> None:
        if exc_type is None:
            self.close()
        else:
            self.abort()

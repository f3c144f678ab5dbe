"""HDR image readers (and a PFM writer): Radiance ``.hdr``, OpenEXR ``.exr``, ``.pfm``.

Every reader returns a ``(H, W, 3)`` float32 **RGB** array whose row 0 is the **top** of the image
(the usual raster order, whatever the file stores), values in linear radiance units as stored.

Which library reads what:

* ``.hdr`` / ``.pic`` (Radiance RGBE, flat or RLE): OpenCV, ``cv2.imread(path, cv2.IMREAD_UNCHANGED)``,
  which returns BGR float32 - converted to RGB here. (imageio would need the FreeImage plugin.)
* ``.exr``: the ``OpenEXR`` Python package (3.x, ``OpenEXR.File``; a base dependency);
  otherwise OpenCV with ``OPENCV_IO_ENABLE_OPENEXR=1`` (set here before cv2 is first imported), which works
  only where the OpenCV build includes OpenEXR (the opencv-python-headless wheels do not).
  RGB(A) or a single luminance channel (``Y``) are accepted; alpha is dropped.
* ``.pfm`` (Portable Float Map): a small numpy reader - ``PF`` (RGB) or ``Pf`` (grey), a negative scale
  means little-endian, rows stored bottom-to-top (flipped here).

Only numpy is imported at module level (no torch: the run-time player uses this package).
"""

from __future__ import annotations

import os
import re
from pathlib import Path

import numpy as np

from prt_torch.errors import PrtError
from prt_torch.io import atomic_write_bytes

#: file suffix -> reader name
FORMATS: dict[str, str] = {".hdr": "radiance", ".pic": "radiance", ".exr": "openexr", ".pfm": "pfm"}


def _cv2():  # type: ignore[no-untyped-def]
    os.environ.setdefault("OPENCV_IO_ENABLE_OPENEXR", "1")
    import cv2

    return cv2


def _check_file(path: str | os.PathLike[str]) -> Path:
    p = Path(path)
    if not p.is_file():
        raise PrtError(f"image file not found: {p}")
    return p


def _as_rgb(img: np.ndarray, path: Path) -> np.ndarray:
    """``(H, W)``, ``(H, W, 1|3|4)`` -> ``(H, W, 3)`` float32 (grey replicated, alpha dropped)."""
    if img.ndim == 2:
        img = img[..., None]
    if img.ndim != 3 or img.shape[2] not in (1, 3, 4) or img.shape[0] < 1 or img.shape[1] < 1:
        raise PrtError(f"{path.name}: unsupported image shape {img.shape}, expected (H, W) or (H, W, 1|3|4)")
    if img.shape[2] == 1:
        img = np.repeat(img, 3, axis=2)
    return np.ascontiguousarray(img[..., :3], dtype=np.float32)


def read_radiance_hdr(path: str | os.PathLike[str]) -> np.ndarray:
    """Read a Radiance RGBE ``.hdr`` with OpenCV; returns ``(H, W, 3)`` float32 RGB, row 0 = top."""
    p = _check_file(path)
    img = _cv2().imread(str(p), -1)  # cv2.IMREAD_UNCHANGED == -1
    if img is None:
        raise PrtError(f"{p.name}: not a readable Radiance .hdr file")
    if img.ndim == 3 and img.shape[2] >= 3:
        img = img[..., 2::-1] if img.shape[2] == 3 else img[..., [2, 1, 0]]  # BGR -> RGB
    return _as_rgb(img, p)


def read_exr(path: str | os.PathLike[str]) -> np.ndarray:
    """Read an OpenEXR file (OpenEXR package, else OpenCV); returns ``(H, W, 3)`` float32 RGB."""
    p = _check_file(path)
    try:
        import OpenEXR
    except ImportError:  # pragma: no cover - a base dependency, missing only in a broken install
        OpenEXR = None
    if OpenEXR is not None:
        try:
            with OpenEXR.File(str(p), separate_channels=True) as f:
                ch = {name: c.pixels for name, c in f.channels().items()}
        except Exception as exc:  # the binding raises RuntimeError/Exception subclasses
            raise PrtError(f"{p.name}: not a readable OpenEXR file ({type(exc).__name__})") from None
        if all(c in ch for c in "RGB"):
            img = np.stack([ch["R"], ch["G"], ch["B"]], axis=-1)
        elif "Y" in ch:
            img = ch["Y"]
        elif "RGB" in ch or "RGBA" in ch:
            img = ch.get("RGB", ch.get("RGBA"))
        else:
            raise PrtError(f"{p.name}: OpenEXR file has no R, G, B or Y channels (has {sorted(ch)})")
        return _as_rgb(np.asarray(img, dtype=np.float32), p)
    img = _cv2().imread(str(p), -1)  # pragma: no cover
    if img is None:  # pragma: no cover
        raise PrtError(f"{p.name}: cannot read OpenEXR: install the OpenEXR Python package (pip install OpenEXR); "
                       f"this OpenCV build has no EXR codec or the file is not OpenEXR")
    if img.ndim == 3 and img.shape[2] >= 3:  # pragma: no cover
        img = img[..., [2, 1, 0]]
    return _as_rgb(img, p)  # pragma: no cover


_PFM_HEADER = re.compile(rb"^(PF|Pf)\s+(\d+)\s+(\d+)\s+([-+0-9.eE]+)\s")


def read_pfm(path: str | os.PathLike[str]) -> np.ndarray:
    """Read a Portable Float Map; returns ``(H, W, 3)`` float32 RGB with row 0 = top.

    Header: ``PF`` (3 channels) or ``Pf`` (1), width, height, scale; scale < 0 = little-endian.
    Pixel rows are stored bottom-to-top and are flipped here.
    """
    p = _check_file(path)
    data = p.read_bytes()
    m = _PFM_HEADER.match(data)
    if m is None:
        raise PrtError(f"{p.name}: not a PFM file (bad header)")
    channels = 3 if m.group(1) == b"PF" else 1
    w, h = int(m.group(2)), int(m.group(3))
    try:
        scale = float(m.group(4))
    except ValueError:
        raise PrtError(f"{p.name}: bad PFM scale {m.group(4)!r}") from None
    if w < 1 or h < 1 or scale == 0:
        raise PrtError(f"{p.name}: bad PFM header (width {w}, height {h}, scale {scale})")
    dtype = np.dtype("<f4" if scale < 0 else ">f4")
    n = w * h * channels
    body = data[m.end():]
    if len(body) < n * 4:
        raise PrtError(f"{p.name}: truncated PFM file ({len(body)} bytes of pixels, expected {n * 4})")
    img = np.frombuffer(body, dtype=dtype, count=n).reshape(h, w, channels)[::-1]
    return _as_rgb(img.astype(np.float32), p)


def write_pfm(path: str | os.PathLike[str], image: np.ndarray, little_endian: bool = True) -> None:
    """Write ``(H, W, 3)`` or ``(H, W)`` float data (row 0 = top) as PFM, atomically."""
    img = np.asarray(image)
    if img.ndim not in (2, 3) or (img.ndim == 3 and img.shape[2] != 3):
        raise PrtError(f"write_pfm: image must be (H, W) or (H, W, 3), got {img.shape}")
    channels = 3 if img.ndim == 3 else 1
    h, w = img.shape[:2]
    header = f"{'PF' if channels == 3 else 'Pf'}\n{w} {h}\n{-1.0 if little_endian else 1.0}\n".encode("ascii")
    body = np.ascontiguousarray(img[::-1], dtype="<f4" if little_endian else ">f4").tobytes()
    atomic_write_bytes(path, header + body)


def read_hdr_image(path: str | os.PathLike[str]) -> np.ndarray:
    """Read any supported HDR image by its suffix (``.hdr``, ``.pic``, ``.exr``, ``.pfm``).

    Returns ``(H, W, 3)`` float32 RGB, row 0 = top. Raises :class:`PrtError` for a missing file or an
    unknown format.
    """
    p = Path(path)
    kind = FORMATS.get(p.suffix.lower())
    if kind is None:
        raise PrtError(f"unknown HDR image format {p.suffix or '(no suffix)'!r} for {p.name}: "
                       f"expected one of {', '.join(sorted(FORMATS))}")
    if kind == "radiance":
        return read_radiance_hdr(p)
    if kind == "openexr":
        return read_exr(p)
    return read_pfm(p)

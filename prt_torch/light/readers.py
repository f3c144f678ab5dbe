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

Malformed files: every reader reads the header first and refuses an image whose float32 RGB pixels would
exceed ``MAX_IMAGE_BYTES`` *before* allocating (the message gives the estimate); truncated pixel data and
NaN/Inf pixels are refused too. Negative radiance (PFM and EXR can store it; it is not light) is clamped to 0
with one :func:`~prt_torch.errors.warn` line giving the number of pixels clamped (:func:`_as_rgb`, the one
pixel rule of every reader). Library chatter (OpenCV log lines, OpenEXR's native messages, Python and
numpy warnings) is silenced around the reads (:func:`quiet_native`), so a bad file gives exactly one
:class:`~prt_torch.errors.PrtError` line.

Only numpy is imported at module level (no torch: the run-time player uses this package).
"""

from __future__ import annotations

import contextlib
import io
import math
import os
import re
import sys
import tempfile
import threading
import warnings
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from prt_torch.errors import PrtError, warn
from prt_torch.io import atomic_write_bytes

#: file suffix -> reader name
FORMATS: dict[str, str] = {".hdr": "radiance", ".pic": "radiance", ".exr": "openexr", ".pfm": "pfm"}

#: the largest image any reader accepts, in bytes of float32 RGB pixels (checked from the header, before reading)
MAX_IMAGE_BYTES = 1 << 30

_STDERR_LOCK = threading.Lock()


class NativeOutput:
    """What library code wrote to stderr inside :func:`quiet_native` (``first_line``: '' when nothing)."""

    def __init__(self) -> None:
        self.lines: list[str] = []

    @property
    def first_line(self) -> str:
        return self.lines[0][:160] if self.lines else ""


@contextlib.contextmanager
def quiet_native() -> Iterator[NativeOutput]:
    """Silence library chatter around a read: Python warnings, numpy floating-point warnings, OpenCV's log
    and anything native code (OpenEXR, OpenCV) writes to file descriptors 1 and 2, which is captured (the yielded
    :class:`NativeOutput` holds it once the block exits) instead of printed."""
    out = NativeOutput()
    cv2 = sys.modules.get("cv2")
    logging = getattr(getattr(cv2, "utils", None), "logging", None)
    level = None
    with warnings.catch_warnings(), np.errstate(all="ignore"), _STDERR_LOCK, tempfile.TemporaryFile() as tmp:
        warnings.simplefilter("ignore")
        if logging is not None:
            with contextlib.suppress(Exception):
                level = logging.getLogLevel()
                logging.setLogLevel(logging.LOG_LEVEL_SILENT)
        saved: dict[int, int] = {}
        for fd, stream in ((1, sys.stdout), (2, sys.stderr)):  # OpenEXR's binding prints to stdout too
            with contextlib.suppress(Exception):
                stream.flush()
            try:
                saved[fd] = os.dup(fd)
                os.dup2(tmp.fileno(), fd)
            except OSError:  # no such descriptor: nothing to silence
                pass
        py_text = io.StringIO()  # Python-level prints (the OpenEXR binding's warnings) wherever sys.stdout points
        try:
            with contextlib.redirect_stdout(py_text), contextlib.redirect_stderr(py_text):
                yield out
        finally:
            for fd, stream in ((1, sys.stdout), (2, sys.stderr)):
                with contextlib.suppress(Exception):
                    stream.flush()  # Python-level text the library printed goes to the capture, not the terminal
                if fd in saved:
                    os.dup2(saved[fd], fd)
                    os.close(saved[fd])
            if level is not None:
                with contextlib.suppress(Exception):
                    logging.setLogLevel(level)
            tmp.seek(0)
            text = py_text.getvalue()[:8192] + tmp.read(8192).decode("utf-8", errors="replace")
            out.lines = [ln.strip() for ln in text.splitlines() if ln.strip()]


def check_image_size(width: int, height: int, name: str) -> None:
    """Refuse a ``width x height`` image from a header before reading it: non-positive sizes, or float32 RGB
    pixels above :data:`MAX_IMAGE_BYTES` (the message gives the estimate)."""
    if width < 1 or height < 1:
        raise PrtError(f"{name}: bad image size {width}x{height} in the header")
    need = width * height * 3 * 4
    if need > MAX_IMAGE_BYTES:
        raise PrtError(f"{name}: refusing a {width}x{height} image: {need / 2**30:.3g} GiB of float32 RGB pixels "
                       f"exceeds the {MAX_IMAGE_BYTES / 2**30:.3g} GiB limit (MAX_IMAGE_BYTES)")


def _cv2():  # type: ignore[no-untyped-def]
    os.environ.setdefault("OPENCV_IO_ENABLE_OPENEXR", "1")
    with quiet_native():
        import cv2

    return cv2


def _check_file(path: str | os.PathLike[str]) -> Path:
    p = Path(path)
    if not p.is_file():
        raise PrtError(f"image file not found: {p}")
    return p


def _as_rgb(img: np.ndarray, path: Path) -> np.ndarray:
    """``(H, W)``, ``(H, W, 1|3|4)`` -> ``(H, W, 3)`` float32 (grey replicated, alpha dropped); NaN/Inf pixels are
    a :class:`PrtError`, negative values are clamped to 0 with a warning saying how many pixels had one."""
    if img.ndim == 2:
        img = img[..., None]
    if img.ndim != 3 or img.shape[2] not in (1, 3, 4) or img.shape[0] < 1 or img.shape[1] < 1:
        raise PrtError(f"{path.name}: unsupported image shape {img.shape}, expected (H, W) or (H, W, 1|3|4)")
    if img.shape[2] == 1:
        img = np.repeat(img, 3, axis=2)
    with np.errstate(all="ignore"):
        out = np.ascontiguousarray(img[..., :3], dtype=np.float32)
    finite = np.isfinite(out).all(axis=2)
    if not finite.all():
        raise PrtError(f"{path.name} contains NaN or Inf in {int((~finite).sum())} pixel(s)")
    negative = (out < 0).any(axis=2)
    if negative.any():
        n = int(negative.sum())
        warn(f"{path.name}: clamped negative radiance to 0 in {n} of {negative.size} pixel(s) "
             f"(lowest value {float(out.min()):.6g})")
        out = np.maximum(out, 0.0)
    return out


_RGBE_RESOLUTION = re.compile(rb"^([-+])([XY]) +(\d+) +([-+])([XY]) +(\d+)$")


def _radiance_header(p: Path) -> tuple[int, int, int]:
    """``(width, height, offset of the pixel data)`` from a Radiance header; :class:`PrtError` if malformed."""
    with open(p, "rb") as f:
        head = f.read(1 << 16)
    if not head.startswith(b"#?"):
        raise PrtError(f"{p.name}: not a readable Radiance .hdr file (no '#?' signature)")
    end = head.find(b"\n\n")
    if end < 0:
        raise PrtError(f"{p.name}: not a readable Radiance .hdr file (header does not end)")
    fmt = re.search(rb"^FORMAT=(\S+)", head[:end], flags=re.MULTILINE)
    if fmt is not None and fmt.group(1) not in (b"32-bit_rle_rgbe", b"32-bit_rle_xyze"):
        raise PrtError(f"{p.name}: unsupported Radiance FORMAT {fmt.group(1)[:30].decode(errors='replace')!r}")
    line_end = head.find(b"\n", end + 2)
    line = head[end + 2:line_end if line_end >= 0 else len(head)].strip()
    m = _RGBE_RESOLUTION.match(line)
    if m is None or m.group(2) == m.group(5):
        raise PrtError(f"{p.name}: not a readable Radiance .hdr file (bad resolution line {line[:40]!r})")
    first, second = int(m.group(3)), int(m.group(6))
    height, width = (first, second) if m.group(2) == b"Y" else (second, first)
    return width, height, (line_end + 1 if line_end >= 0 else len(head))


def read_radiance_hdr(path: str | os.PathLike[str]) -> np.ndarray:
    """Read a Radiance RGBE ``.hdr`` with OpenCV; returns ``(H, W, 3)`` float32 RGB, row 0 = top.

    The header is parsed here first: an absurd resolution is refused before OpenCV allocates, and a file
    shorter than the smallest possible encoding of its pixels is reported as truncated.
    """
    p = _check_file(path)
    w, h, start = _radiance_header(p)
    check_image_size(w, h, p.name)
    # smallest encoding of a scanline: new-style RLE (4-byte marker, runs of <= 127 per channel) or flat RGBE
    rle = 4 + 8 * math.ceil(w / 127) if 8 <= w < 32768 else 4 * w
    least = h * min(4 * w, rle)
    have = p.stat().st_size - start
    if have < least:
        raise PrtError(f"{p.name}: truncated Radiance file ({have} bytes of pixels, a {w}x{h} image needs at "
                       f"least {least})")
    cv2 = _cv2()
    with quiet_native() as native:
        img = cv2.imread(str(p), -1)  # cv2.IMREAD_UNCHANGED == -1
    if img is None:
        detail = native.first_line.split("error:")[-1].strip() if native.first_line else ""
        raise PrtError(f"{p.name}: not a readable Radiance .hdr file (truncated or corrupt"
                       f"{': ' + detail[:100] if detail else ''})")
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
        failure: Exception | None = None
        with quiet_native() as native:
            try:
                with OpenEXR.File(str(p), header_only=True) as f:
                    (x0, y0), (x1, y1) = (np.asarray(c, dtype=np.int64) for c in f.header()["dataWindow"])
            except Exception as exc:  # the binding raises RuntimeError/ValueError/Exception subclasses
                failure = exc
        if failure is not None:
            raise PrtError(f"{p.name}: not a readable OpenEXR file ({type(failure).__name__}"
                           f"{': ' + native.first_line[:100] if native.first_line else ''})")
        check_image_size(int(x1) - int(x0) + 1, int(y1) - int(y0) + 1, p.name)
        with quiet_native() as native:
            try:
                with OpenEXR.File(str(p), separate_channels=True) as f:
                    ch = {name: c.pixels for name, c in f.channels().items()}
            except Exception as exc:
                failure = exc
        if failure is not None:
            raise PrtError(f"{p.name}: not a readable OpenEXR file ({type(failure).__name__}"
                           f"{': ' + native.first_line[:100] if native.first_line else ''})")
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
    with open(p, "rb") as f:
        head = f.read(256)
    m = _PFM_HEADER.match(head)
    if m is None:
        raise PrtError(f"{p.name}: not a PFM file (bad header)")
    channels = 3 if m.group(1) == b"PF" else 1
    w, h = int(m.group(2)), int(m.group(3))
    try:
        scale = float(m.group(4))
    except ValueError:
        raise PrtError(f"{p.name}: bad PFM scale {m.group(4)[:30]!r}") from None
    if w < 1 or h < 1 or scale == 0 or not math.isfinite(scale):
        raise PrtError(f"{p.name}: bad PFM header (width {w}, height {h}, scale {scale})")
    check_image_size(w, h, p.name)
    dtype = np.dtype("<f4" if scale < 0 else ">f4")
    n = w * h * channels
    have = p.stat().st_size - m.end()
    if have < n * 4:
        raise PrtError(f"{p.name}: truncated PFM file ({have} bytes of pixels, expected {n * 4})")
    with open(p, "rb") as f:
        f.seek(m.end())
        body = f.read(n * 4)
    if len(body) < n * 4:
        raise PrtError(f"{p.name}: truncated PFM file ({len(body)} bytes of pixels, expected {n * 4})")
    img = np.frombuffer(body, dtype=dtype, count=n).reshape(h, w, channels)[::-1]
    return _as_rgb(img, p)


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

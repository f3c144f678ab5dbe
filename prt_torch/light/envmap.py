"""Environment maps: pixel <-> direction mappings, exact pixel solid angles, SH projection.

Frames (world is right-handed, **z up**, see ``docs/DESIGN.md``):

* **Image frame**: HDR images are authored y-up: ``x`` right, ``y`` up, ``z`` toward the viewer
  (OpenGL camera frame). A y-up direction ``(x, y, z)`` maps to world z-up ``(x, -z, y)`` - the same
  rotation the glTF loader applies - so image "forward" ``-z`` is world ``+y``.
* **Lat-long** (equirectangular, aspect 2:1), pixel ``(row, col)`` of an ``H x W`` image with centre
  ``u = (col + 0.5) / W``, ``v = (row + 0.5) / H`` in ``[0, 1)``::

      theta = pi * v                       (polar angle from world +z; row 0 = straight up)
      phi   = pi/2 - 2 pi (u - 1/2)        (azimuth measured from +x toward +y)
      w     = (sin theta cos phi, sin theta sin phi, cos theta)

  so the image centre (``u = 1/2``) looks along world ``+y`` (image-frame forward ``-z``), ``u = 3/4`` is
  world ``+x`` (right of the centre, as seen from inside the sphere), ``u = 1/4`` is ``-x`` and the
  left/right edges are ``-y``. Pixel ``(row, col)`` covers ``theta in [pi row/H, pi (row+1)/H]`` and an
  azimuth interval of ``2 pi / W``; its exact solid angle is ``(2 pi / W) (cos theta_top - cos theta_bottom)``.
* **Angular map** (Debevec light probe, square): with ``a = 2 u - 1`` (right +) and ``b = 1 - 2 v`` (up +),
  ``r = sqrt(a^2 + b^2) <= 1``, Debevec's mapping in the y-up image frame is
  ``(Dx, Dy, Dz) = (sin(pi r) a / r, sin(pi r) b / r, cos(pi r))``: the centre is image ``+z`` (toward the
  camera that photographed the mirror ball), the rim ``r = 1`` is image ``-z``. In world coordinates
  ``w = (Dx, -Dz, Dy)``: the centre looks along world ``-y``, image up is world ``+z``. Area element
  ``d omega = pi sin(pi r) / r da db = pi^2 sinc(r) da db``; pixel solid angles integrate it over each pixel
  (Gauss-Legendre sub-samples, clipped to the disk), and pixels outside the disk weigh 0.

Everything here is numpy (no torch: the run-time player uses this module).
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import numpy as np

from prt_torch.errors import PrtError
from prt_torch.light.readers import read_hdr_image
from prt_torch.sh.basis import check_directions, check_order, sh_basis
from prt_torch.shapes import check_shape

Layout = Literal["latlong", "probe"]
LAYOUTS: tuple[str, ...] = ("latlong", "probe")

#: Gauss-Legendre sub-samples per pixel side for the angular-map solid angles.
PROBE_SUBSAMPLES = 6

#: Rec. 709 luminance weights (luminance = ``rgb @ LUMA``)
LUMA = np.array([0.2126, 0.7152, 0.0722])

#: pixels per SH-projection chunk (bounds the ``(chunk, C)`` basis array).
_CHUNK = 1 << 16


def check_image(image: np.ndarray, name: str = "environment map") -> np.ndarray:
    """Validate a ``(H, W, 3)`` finite image; returns it as float32. Raises :class:`PrtError`."""
    if not isinstance(image, np.ndarray):
        raise PrtError(f"{name} must be a numpy array, got {type(image).__name__}")
    check_shape(image, "H W 3", name=name)
    if image.shape[0] < 1 or image.shape[1] < 1:
        raise PrtError(f"{name} must have shape (H, W, 3), got {image.shape}")
    if not np.issubdtype(image.dtype, np.number):
        raise PrtError(f"{name} must be numeric, got {image.dtype}")
    if not np.isfinite(image).all():
        bad = int((~np.isfinite(image)).any(axis=2).sum())
        raise PrtError(f"{name} contains NaN or Inf in {bad} pixel(s)")
    return image.astype(np.float32, copy=False)


def infer_layout(height: int, width: int) -> Layout:
    """``"latlong"`` for a 2:1 image, ``"probe"`` for a square one; else :class:`PrtError`."""
    if width == 2 * height:
        return "latlong"
    if width == height:
        return "probe"
    raise PrtError(f"cannot infer the environment-map layout of a {width}x{height} image: expected 2:1 (latlong) or "
                   f"1:1 (probe); pass layout= explicitly")


def _check_layout(layout: str) -> None:
    if layout not in LAYOUTS:
        raise PrtError(f"unknown environment-map layout {layout!r}: expected one of {', '.join(LAYOUTS)} or 'auto'")


# ----------------------------------------------------------------------------------------------- lat-long


def latlong_directions(height: int, width: int) -> np.ndarray:
    """World directions of lat-long pixel centres, ``(H, W, 3)`` float64 (see module docstring)."""
    theta = np.pi * (np.arange(height) + 0.5) / height
    u = (np.arange(width) + 0.5) / width
    phi = np.pi / 2 - 2 * np.pi * (u - 0.5)
    st = np.sin(theta)[:, None]
    return np.stack(np.broadcast_arrays(st * np.cos(phi)[None, :], st * np.sin(phi)[None, :],
                                        np.cos(theta)[:, None]), axis=-1)


def latlong_solid_angles(height: int, width: int) -> np.ndarray:
    """Exact solid angle of every lat-long pixel, ``(H, W)`` float64; sums to ``4 pi``."""
    ct = np.cos(np.pi * np.arange(height + 1) / height)
    rows = (2 * np.pi / width) * (ct[:-1] - ct[1:])
    return np.repeat(rows[:, None], width, axis=1)


def latlong_pixel_coords(dirs: np.ndarray) -> np.ndarray:
    """Inverse mapping: world unit directions ``(..., 3)`` -> continuous ``(..., 2)`` ``(u, v)`` in ``[0, 1)``.

    ``col = u * W`` and ``row = v * H`` locate the direction in an ``H x W`` lat-long image.
    """
    check_directions(dirs)
    d = np.asarray(dirs, dtype=np.float64)
    v = np.arccos(np.clip(d[..., 2], -1.0, 1.0)) / np.pi
    phi = np.arctan2(d[..., 1], d[..., 0])
    u = np.mod(0.5 + (np.pi / 2 - phi) / (2 * np.pi), 1.0)
    return np.stack([u, v], axis=-1)


# ----------------------------------------------------------------------------------------------- angular map


def _probe_ab(height: int, width: int) -> tuple[np.ndarray, np.ndarray]:
    a = 2 * (np.arange(width) + 0.5) / width - 1
    b = 1 - 2 * (np.arange(height) + 0.5) / height
    return np.broadcast_arrays(a[None, :], b[:, None])


def _probe_dirs_from_ab(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    r = np.hypot(a, b)
    rc = np.minimum(r, 1.0)
    s = np.sin(np.pi * rc) / np.where(r > 0, r, 1.0)
    dx, dy, dz = s * a, s * b, np.cos(np.pi * rc)
    d = np.stack([dx, -dz, dy], axis=-1)  # y-up image frame -> z-up world
    return d / np.linalg.norm(d, axis=-1, keepdims=True)


def probe_directions(height: int, width: int) -> np.ndarray:
    """World directions of angular-map pixel centres, ``(H, W, 3)`` float64.

    Pixels outside the unit disk get the rim direction (world ``+y``); their solid angle is 0.
    """
    a, b = _probe_ab(height, width)
    return _probe_dirs_from_ab(a, b)


def probe_solid_angles(height: int, width: int, subsamples: int = PROBE_SUBSAMPLES) -> np.ndarray:
    """Solid angle of every angular-map pixel, ``(H, W)`` float64: ``pi^2 sinc(r)`` integrated over the pixel.

    ``subsamples x subsamples`` Gauss-Legendre points per pixel, clipped to the disk ``r <= 1``;
    the total approximates ``4 pi`` (relative error ~1e-5 at 128 x 128).
    """
    x, wq = np.polynomial.legendre.leggauss(subsamples)
    da, db = 2.0 / width, 2.0 / height
    a0, b0 = _probe_ab(height, width)
    out = np.zeros((height, width))
    for i in range(subsamples):  # subsamples**2 (36) passes over the image, each vectorised
        for j in range(subsamples):
            a = a0 + 0.5 * da * x[i]
            b = b0 + 0.5 * db * x[j]
            r = np.hypot(a, b)
            out += wq[i] * wq[j] * np.where(r <= 1.0, np.pi**2 * np.sinc(r), 0.0)
    return out * (0.25 * da * db)


def probe_pixel_coords(dirs: np.ndarray) -> np.ndarray:
    """Inverse mapping: world unit directions ``(..., 3)`` -> ``(..., 2)`` ``(u, v)`` in ``[0, 1]`` of a probe."""
    check_directions(dirs)
    d = np.asarray(dirs, dtype=np.float64)
    dx, dy, dz = d[..., 0], d[..., 2], -d[..., 1]  # world -> y-up image frame
    rho = np.hypot(dx, dy)
    r = np.arccos(np.clip(dz, -1.0, 1.0)) / np.pi
    ok = rho > 1e-12
    scale = r / np.where(ok, rho, 1.0)
    a = np.where(ok, dx * scale, r)  # the centre (r = 0) or the rim point (r = 1, any azimuth: pick +a)
    b = np.where(ok, dy * scale, 0.0)
    return np.stack([(a + 1) / 2, (1 - b) / 2], axis=-1)


# ----------------------------------------------------------------------------------------------- EnvMap


@dataclass
class EnvMap:
    """An HDR environment map: ``image (H, W, 3)`` float32 linear RGB (row 0 = top) in a ``layout``.

    ``layout`` is ``"latlong"`` or ``"probe"`` (see the module docstring for both mappings).
    """

    image: np.ndarray
    layout: Layout
    source: str = ""
    _cache: dict[str, np.ndarray] = field(default_factory=dict, repr=False, compare=False)

    def __post_init__(self) -> None:
        self.image = check_image(self.image)
        _check_layout(self.layout)
        h, w = self.image.shape[:2]
        if self.layout == "latlong" and w != 2 * h:
            raise PrtError(f"a lat-long environment map must be 2:1, got {w}x{h}")
        if self.layout == "probe" and w != h:
            raise PrtError(f"an angular-map (probe) environment map must be square, got {w}x{h}")

    @property
    def shape(self) -> tuple[int, int]:
        """``(H, W)``."""
        return self.image.shape[0], self.image.shape[1]

    def directions(self) -> np.ndarray:
        """World directions of the pixel centres, ``(H, W, 3)`` float64."""
        if "dirs" not in self._cache:
            h, w = self.shape
            self._cache["dirs"] = latlong_directions(h, w) if self.layout == "latlong" else probe_directions(h, w)
        return self._cache["dirs"]

    def solid_angles(self) -> np.ndarray:
        """Solid angle of every pixel, ``(H, W)`` float64 (sums to ~``4 pi``)."""
        if "omega" not in self._cache:
            h, w = self.shape
            self._cache["omega"] = (latlong_solid_angles(h, w) if self.layout == "latlong"
                                    else probe_solid_angles(h, w))
        return self._cache["omega"]

    def to_sh(self, order: int) -> np.ndarray:
        """SH coefficients ``(C, 3)`` float64; see :func:`envmap_to_sh`."""
        return envmap_to_sh(self, order)


def load_envmap(path: str | os.PathLike[str], layout: str = "auto") -> EnvMap:
    """Read an HDR environment map (``.hdr``, ``.exr``, ``.pfm``).

    ``layout="auto"`` picks ``"latlong"`` for a 2:1 image and ``"probe"`` for a square one.
    Raises :class:`PrtError` for a missing file, unknown format, unknown layout, NaN/Inf pixels.
    """
    if layout != "auto":
        _check_layout(layout)
    img = read_hdr_image(path)
    img = check_image(img, f"environment map {Path(path).name}")
    lay = infer_layout(*img.shape[:2]) if layout == "auto" else layout
    return EnvMap(img, lay, source=str(path))  # type: ignore[arg-type]


def project_samples(values: np.ndarray, dirs: np.ndarray, weights: np.ndarray, order: int) -> np.ndarray:
    """Weighted SH projection ``sum_p values_p y(dirs_p) weights_p`` in chunks.

    Args:
        values: ``(N, 3)`` samples.
        dirs: ``(N, 3)`` unit directions.
        weights: ``(N,)`` quadrature weights (solid angles).
        order: SH order ``n``.

    Returns:
        ``(C, 3)`` float64, ``C = n*n``.
    """
    check_order(order)
    out = np.zeros((order * order, values.shape[1]))
    keep = weights != 0
    values, dirs, weights = values[keep], dirs[keep], weights[keep]
    for s in range(0, len(weights), _CHUNK):
        y = sh_basis(dirs[s:s + _CHUNK], order, check=False)
        out += y.T @ (values[s:s + _CHUNK].astype(np.float64) * weights[s:s + _CHUNK, None])
    return out


def envmap_to_sh(env: EnvMap, order: int) -> np.ndarray:
    """Project an environment map onto real SH: ``l_i = sum_pixels L(p) y_i(w_p) Omega_p``.

    ``w_p`` are pixel-centre world directions (z up) and ``Omega_p`` the pixel solid angles (exact for
    lat-long). Coefficients are orthonormal-basis projections (``L00 = mean radiance * sqrt(4 pi)``
    weighted by solid angle), e.g. ``uffizi.hdr`` gives ``L00 = (3.172, 3.077, 3.501)``.

    Returns:
        ``(C, 3)`` float64 RGB, ``C = order**2``, in the project's index order ``l*(l+1)+m``.
    """
    check_order(order)
    if not isinstance(env, EnvMap):
        raise PrtError(f"envmap_to_sh expects an EnvMap, got {type(env).__name__}")
    h, w = env.shape
    return project_samples(env.image.reshape(-1, 3), env.directions().reshape(-1, 3),
                           env.solid_angles().reshape(-1), order)

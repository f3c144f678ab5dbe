"""The light split (issue 27): a lighting = up to ``K`` peak lights + a smooth residual environment map.

Order-4 SH resolves about 45 degrees, so a sun - a disc of a fraction of a degree holding half of an outdoor map's
power - is smeared over the sky and casts no shadow. The split takes the peaks out so that each can get its own
visibility, and leaves the rest (the *residual*, an :class:`~prt_torch.light.envmap.EnvMap`) to today's SH / ZH-lobe
path unchanged (``split.residual.to_sh(order)``).

* A **peak light** (:class:`PeakLight`) is a uniform disc: unit ``direction (3,)`` (world frame, z up), angular
  radius ``r`` (half-angle, radians; degrees in JSON) and RGB radiance ``(3,)`` (W / (sr m^2), constant over the
  disc). Its solid angle is ``2 pi (1 - cos r)`` and its power ``radiance * solid_angle`` (the irradiance it
  delivers to a surface facing it, up to ``(1 + cos r) / 2``; ``E`` of :func:`prt_torch.light.sources.sky_sh`).
* **Environment maps** (:func:`split_envmap`, any layout): the peaks are found by seed 004's detection
  (:func:`prt_torch.sg.lighting.detect_peaks`: threshold + connected components on HEALPix, strongest first, at
  most ``K``). Each component's map pixels (``Peak.pixels``) are replaced by a smooth fill: the solid-angle-weighted
  mean of the *ring* of map pixels around it (not in any component, within ``extent + max(3 pixel sizes,
  extent / 2)`` of the peak's direction, ``extent`` the largest angle of a component pixel), clamped per pixel and
  channel to the pixel's own value, so that nothing negative is removed. The removed light ``excess = L - fill``
  is the peak: its power is ``sum excess Omega`` (per channel), its direction the excess-luminance-weighted mean
  direction, its solid angle that of the component pixels at or above half the maximum excess luminance (exact for
  a uniform disc on any background: a pixel counts when the disc covers at least half of it), its angular radius
  the disc's of that solid angle (or ``angular_radius`` when given), its radiance ``power / solid_angle``. Energy
  is conserved per channel by construction: ``sum_peaks power + sum_residual L Omega = sum_map L Omega``.
* The **procedural sky** (:func:`split_sky`): its sun is a peak by construction (no detection), a disc of
  ``sun_angular_radius`` (default the real sun's, :data:`~prt_torch.light.sources.SUN_HALF_ANGLE` = 0.265 deg)
  and power ``sun_color`` (as :func:`~prt_torch.light.sources.sky_sh`); the residual is
  :func:`~prt_torch.light.sources.sky_envmap` (the sky and ground without the sun). A sun below the horizon is
  no peak.

JSON (:meth:`LightSplit.to_dict`, what ``prt light FILE --peaks --json`` prints and ``compare.json`` will carry):
``{"peaks": [{"direction": [x, y, z], "angular_radius_deg": r, "radiance": [r, g, b]}, ...]}``.

numpy only at import: the procedural sky's split never imports torch; :func:`split_envmap` needs the ``sg``
extra (healpy, torch) for the detection and says so in one line without it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from prt_torch.errors import PrtError, check
from prt_torch.light.envmap import LUMA, EnvMap, envmap_to_sh
from prt_torch.light.sources import DEFAULT_SUN, SUN_HALF_ANGLE, directional_light_sh, sky_envmap

#: peak lights by default (``prt light --peaks``) and at most
DEFAULT_PEAKS = 2
MAX_PEAKS = 4

#: the procedural sky's sun: the real sun's angular radius (radians)
SUN_ANGULAR_RADIUS = SUN_HALF_ANGLE

#: ring width around a peak's component, in mean map-pixel sizes (at least), and as a fraction of its extent
RING_PIXELS = 3.0
RING_FRACTION = 0.5


def disc_solid_angle(angular_radius: float | np.ndarray) -> float | np.ndarray:
    """Solid angle of a spherical cap of half-angle ``angular_radius`` (radians): ``2 pi (1 - cos r)``, evaluated
    as ``4 pi sin^2(r / 2)`` (no cancellation for a sun-sized ``r``)."""
    return 4 * np.pi * np.sin(np.asarray(angular_radius, dtype=np.float64) / 2) ** 2 if np.ndim(angular_radius) \
        else 4 * math.pi * math.sin(float(angular_radius) / 2) ** 2


def disc_angular_radius(solid_angle: float) -> float:
    """Inverse of :func:`disc_solid_angle`: ``acos(1 - omega / (2 pi))`` radians, for ``omega in (0, 4 pi]``."""
    check(math.isfinite(solid_angle) and 0 < solid_angle <= 4 * math.pi,
          f"a disc's solid angle must be in (0, 4 pi] sr, got {solid_angle}")
    return math.acos(max(-1.0, 1 - solid_angle / (2 * math.pi)))


def check_peak_count(k: object, name: str = "peaks") -> int:
    """``k`` as an int in ``0..MAX_PEAKS`` or a one-line :class:`PrtError`."""
    ok = isinstance(k, (int, np.integer)) and not isinstance(k, bool) and 0 <= int(k) <= MAX_PEAKS
    check(ok, f"{name} must be an integer in 0..{MAX_PEAKS}, got {k!r}")
    return int(k)  # type: ignore[arg-type]


def check_angular_radius(r: object, name: str = "angular radius") -> float:
    """A disc half-angle in radians, finite and in ``(0, pi/2]``, or a one-line :class:`PrtError`."""
    try:
        v = float(r)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        raise PrtError(f"{name} must be a number of radians, got {r!r}") from None
    check(math.isfinite(v) and 0 < v <= math.pi / 2, f"{name} must be in (0, 90] degrees, got {math.degrees(v):g}")
    return v


@dataclass
class PeakLight:
    """A uniform disc light.

    Attributes:
        direction: ``(3,)`` float64 unit vector toward the disc's centre, world frame (z up).
        angular_radius: the disc's half-angle, radians (``angular_radius_deg`` in JSON).
        radiance: ``(3,)`` float64 RGB radiance of the disc, W / (sr m^2), uniform over it.
    """

    direction: np.ndarray
    angular_radius: float
    radiance: np.ndarray

    def __post_init__(self) -> None:
        d = np.asarray(self.direction, dtype=np.float64)
        check(d.shape == (3,) and bool(np.isfinite(d).all()) and np.linalg.norm(d) > 0,
              f"a peak light's direction must be a finite non-zero (3,) vector, got {d.tolist()}")
        self.direction = d / np.linalg.norm(d)
        self.angular_radius = check_angular_radius(self.angular_radius, "a peak light's angular radius")
        rad = np.asarray(self.radiance, dtype=np.float64)
        check(rad.shape == (3,) and bool(np.isfinite(rad).all()) and bool((rad >= 0).all()),
              f"a peak light's radiance must be a finite non-negative RGB triple, got {rad.tolist()}")
        self.radiance = rad

    @property
    def solid_angle(self) -> float:
        """``2 pi (1 - cos r)`` steradians."""
        return float(disc_solid_angle(self.angular_radius))

    @property
    def power(self) -> np.ndarray:
        """``(3,)`` RGB ``radiance * solid_angle`` (the disc's integral; ``E`` of a disk light)."""
        return self.radiance * self.solid_angle

    @property
    def elevation_azimuth_deg(self) -> tuple[float, float]:
        """Elevation above the horizon and azimuth from ``+x`` toward ``+y``, degrees."""
        x, y, z = self.direction
        return math.degrees(math.asin(max(-1.0, min(1.0, z)))), math.degrees(math.atan2(y, x)) % 360.0

    def to_sh(self, order: int) -> np.ndarray:
        """SH ``(C, 3)`` float64 of the disc (:func:`prt_torch.light.sources.directional_light_sh`, a cap)."""
        return directional_light_sh(self.direction, self.power, order, self.angular_radius)

    def to_dict(self) -> dict[str, Any]:
        """``{"direction": [x, y, z], "angular_radius_deg": r, "radiance": [r, g, b]}`` (the compare.json schema)."""
        return {"direction": self.direction.tolist(), "angular_radius_deg": math.degrees(self.angular_radius),
                "radiance": self.radiance.tolist()}

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> PeakLight:
        """Inverse of :meth:`to_dict`; a missing key is a one-line :class:`PrtError`."""
        for key in ("direction", "angular_radius_deg", "radiance"):
            check(key in d, f"a peak light needs {key!r}, got keys {sorted(d)}")
        return cls(np.asarray(d["direction"], dtype=np.float64), math.radians(float(d["angular_radius_deg"])),
                   np.asarray(d["radiance"], dtype=np.float64))


@dataclass
class LightSplit:
    """A lighting as ``peaks + residual``: up to :data:`MAX_PEAKS` :class:`PeakLight` (strongest first) and the
    smooth rest, an :class:`EnvMap` (world frame, z up) for the SH / ZH-lobe path."""

    peaks: list[PeakLight]
    residual: EnvMap
    source: str = ""
    _cache: dict[str, np.ndarray] = field(default_factory=dict, repr=False, compare=False)

    def residual_power(self) -> np.ndarray:
        """``(3,)`` RGB ``sum L Omega`` of the residual map."""
        if "residual_power" not in self._cache:
            om = self.residual.solid_angles().reshape(-1)
            self._cache["residual_power"] = om @ self.residual.image.reshape(-1, 3).astype(np.float64)
        return self._cache["residual_power"]

    def peak_power(self) -> np.ndarray:
        """``(K, 3)`` RGB power of each peak."""
        return np.array([p.power for p in self.peaks]).reshape(-1, 3)

    def total_power(self) -> np.ndarray:
        """``(3,)`` RGB power of the whole lighting (peaks + residual)."""
        return self.peak_power().sum(0) + self.residual_power()

    def shares(self) -> np.ndarray:
        """``(K,)`` each peak's share of the lighting's luminous power (Rec. 709 luminance)."""
        total = float(self.total_power() @ LUMA)
        return self.peak_power() @ LUMA / total if total > 0 else np.zeros(len(self.peaks))

    def to_sh(self, order: int, peaks: bool = True) -> np.ndarray:
        """SH ``(C, 3)`` float64: the residual's (:func:`~prt_torch.light.envmap.envmap_to_sh`), plus with
        ``peaks`` every peak as a cap (the whole lighting again, up to the fill inside the discs)."""
        sh = envmap_to_sh(self.residual, order)
        for p in self.peaks if peaks else ():
            sh = sh + p.to_sh(order)
        return sh

    def to_dict(self) -> dict[str, Any]:
        """``{"peaks": [PeakLight.to_dict(), ...]}``."""
        return {"peaks": [p.to_dict() for p in self.peaks]}


# ------------------------------------------------------------------------------------------------ the sky


def split_sky(sun_direction: object = DEFAULT_SUN, sun_color: object = (30.0, 28.0, 24.0),
              sky_color: object = (0.35, 0.55, 1.0), ground_color: object = (0.25, 0.22, 0.2),
              sun_angular_radius: float = SUN_ANGULAR_RADIUS, height: int = 128) -> LightSplit:
    """The procedural sky (:func:`prt_torch.light.sources.sky_sh`'s arguments) split: its sun a peak of angular
    radius ``sun_angular_radius`` (radians) and power ``sun_color`` (radiance ``sun_color / (2 pi (1 - cos r))``),
    the residual :func:`~prt_torch.light.sources.sky_envmap` (``2H x H`` lat-long, no sun). No peak when the sun
    is below the horizon. Torch-free."""
    r = check_angular_radius(sun_angular_radius, "sun angular radius")
    residual = sky_envmap(sun_direction, sky_color, ground_color, height)
    s = np.asarray(sun_direction, dtype=np.float64)
    s = s / np.linalg.norm(s)  # sky_envmap checked it
    e = np.asarray(sun_color, dtype=np.float64)
    e = np.full(3, float(e)) if e.ndim == 0 else e
    check(e.shape == (3,) and bool(np.isfinite(e).all()) and bool((e >= 0).all()),
          f"sun color must be a finite non-negative scalar or RGB triple, got {e.tolist()}")
    peaks = [PeakLight(s, r, e / disc_solid_angle(r))] if s[2] > 0 else []
    return LightSplit(peaks, residual, source="procedural sky")


# ------------------------------------------------------------------------------------------------ maps


def _detect_peaks() -> Any:
    try:
        from prt_torch.sg.lighting import detect_peaks, require_healpy

        require_healpy()
    except ImportError as exc:
        raise PrtError(f"the light split of an environment map needs {exc.name}: pip install 'prt-torch[sg]'") \
            from None
    return detect_peaks


def split_envmap(env: EnvMap, max_peaks: int = DEFAULT_PEAKS, angular_radius: float | None = None,
                 sigma: float = 4.0, min_power: float = 0.005, nside: int | None = None) -> LightSplit:
    """Split an environment map into up to ``max_peaks`` peak lights and a smooth residual (module docstring).

    Args:
        env: the map (lat-long or probe), world frame z up.
        max_peaks: ``K`` in ``0..MAX_PEAKS`` (0: no peak, the residual is the map).
        angular_radius: every peak's half-angle in radians instead of the measured one (the removed power is the
            same; the radiance follows).
        sigma, min_power, nside: the detection's threshold, smallest kept share of luminous power and HEALPix
            resolution (:func:`prt_torch.sg.lighting.detect_peaks`).

    Returns:
        :class:`LightSplit` (peaks strongest first; the residual a new map of the same layout and size).
    """
    check(isinstance(env, EnvMap), f"split_envmap expects an EnvMap, got {type(env).__name__}")
    k = check_peak_count(max_peaks, "max_peaks")
    r_fixed = None if angular_radius is None else check_angular_radius(angular_radius)
    src = f"{env.source or env.layout} (residual)"
    if k == 0:
        return LightSplit([], EnvMap(env.image.copy(), env.layout, src), source=env.source)
    found = _detect_peaks()(env, nside=nside, sigma=sigma, min_power=min_power, max_peaks=k)
    img = env.image.reshape(-1, 3).astype(np.float64)
    dirs = env.directions().reshape(-1, 3)
    om = env.solid_angles().reshape(-1)
    taken = np.zeros(len(om), dtype=bool)
    for p in found:
        taken[p.pixels] = True
    free = ~taken & (om > 0)
    pixel_size = math.sqrt(4 * math.pi / max(int((om > 0).sum()), 1))
    out = img.copy()
    peaks: list[PeakLight] = []
    for p in found:  # at most MAX_PEAKS, each vectorised over its pixels and the map
        pix = p.pixels
        if len(pix) == 0:
            continue
        axis = np.asarray(p.direction, dtype=np.float64)
        extent = float(np.arccos(np.clip(dirs[pix] @ axis, -1.0, 1.0)).max())
        outer = min(math.pi, extent + max(RING_PIXELS * pixel_size, RING_FRACTION * extent))
        ring = free & (dirs @ axis >= math.cos(outer))
        fill = (om[ring] @ img[ring]) / om[ring].sum() if ring.any() else np.zeros(3)
        kept = np.minimum(img[pix], fill[None, :])
        excess = img[pix] - kept  # (P, 3) >= 0
        w = om[pix]
        lum = excess @ LUMA
        if not (lum * w).sum() > 0:
            continue
        out[pix] = kept
        power = w @ excess
        m = (lum * w) @ dirs[pix]
        half = lum >= 0.5 * lum.max()
        r = r_fixed if r_fixed is not None else min(disc_angular_radius(float(w[half].sum())), math.pi / 2)
        peaks.append(PeakLight(m / np.linalg.norm(m), r, power / disc_solid_angle(r)))
    residual = EnvMap(out.reshape(env.image.shape).astype(np.float32), env.layout, src)
    return LightSplit(peaks, residual, source=env.source)

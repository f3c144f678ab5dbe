"""Run-time lighting: environment map -> SH -> ZH lobes (numpy + scipy, no torch).

Done once at start (seed 003 sec. 5.5): the env map is projected to order-``n`` SH
(:func:`prt_torch.light.envmap_to_sh`) and approximated by ``K`` zonal-harmonic lobes
(:func:`prt_torch.sh.zhfit.fit_zh_lobes`); the shading graph rotates the ``K`` lobe axes into each
vertex frame. Rotating the light at run time only rotates the ``K`` axes.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from prt_torch.conventions import BELOW_HORIZON
from prt_torch.errors import PrtError
from prt_torch.shapes import check_shape


@dataclass(frozen=True)
class Lighting:
    """``K`` ZH lobes: ``dirs (K, 3)`` float32 unit world axes, ``coeffs (K, n, 3)`` float32 RGB per band,
    the SH they approximate ``sh (C, 3)`` float64, the fit's relative error and a description."""

    dirs: np.ndarray
    coeffs: np.ndarray
    sh: np.ndarray
    rel_error: float
    source: str

    def rotated_about_z(self, angle: float) -> Lighting:
        """The same lighting rotated by ``angle`` radians about the world z (up) axis."""
        c, s = np.cos(angle), np.sin(angle)
        R = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
        dirs = (self.dirs.astype(np.float64) @ R.T).astype(np.float32)
        from prt_torch.light.rotation import rotate_lighting

        return Lighting(dirs, self.coeffs, rotate_lighting(self.sh, R), self.rel_error, self.source)


#: sun power of the default procedural sky (moderate, so that sky-lit and shadowed parts stay visible)
DEFAULT_SUN_COLOR = (8.0, 7.4, 6.4)
#: sun direction of the default sky: high, front-right of the default camera (which looks along +y)
DEFAULT_SUN_DIRECTION = (0.45, -0.55, 0.70)


def sinc_window(order: int) -> np.ndarray:
    """``(C,)`` Lanczos sigma factors ``sinc(l / order)`` per coefficient: damps the ringing (negative
    lobes) of truncated SH lighting such as a sun (Sloan, "Stupid SH tricks", sec. 5)."""
    from prt_torch.sh.basis import band_of

    return np.sinc(band_of(order) / order)


def lighting_from_sh(sh: np.ndarray, n_lobes: int = 3, source: str = "sh", window: bool = True) -> Lighting:
    """Fit ``n_lobes`` ZH lobes to SH lighting ``(C, 3)`` (windowed with :func:`sinc_window` by default)."""
    from prt_torch.sh.basis import order_from_coeffs
    from prt_torch.sh.zhfit import fit_zh_lobes

    sh = np.asarray(sh, dtype=np.float64)
    check_shape(sh, "C 3", name="SH lighting")
    if not np.isfinite(sh).all():
        raise PrtError("SH lighting contains NaN or Inf")
    if window:
        sh = sh * sinc_window(order_from_coeffs(sh.shape[0]))[:, None]
    lobes = fit_zh_lobes(sh, n_lobes)
    return Lighting(np.ascontiguousarray(lobes.dirs, dtype=np.float32),
                    np.ascontiguousarray(lobes.coeffs, dtype=np.float32), sh, float(lobes.rel_error), source)


def load_lighting(env: str | os.PathLike[str] | None, order: int, n_lobes: int = 3, window: bool = True) -> Lighting:
    """Lighting for the player: an HDR env map file, or ``None`` for the procedural sun + sky."""
    if env is None or str(env) in ("", "sky"):
        from prt_torch.light import sources

        sun = np.array(DEFAULT_SUN_DIRECTION) / np.linalg.norm(DEFAULT_SUN_DIRECTION)
        sky = sources.sky_sh(order, sun_direction=sun, sun_color=DEFAULT_SUN_COLOR)
        return lighting_from_sh(sky, n_lobes, source="procedural sky",
                                window=window)
    from prt_torch.light.envmap import envmap_to_sh, load_envmap

    path = Path(env)
    if not path.is_file():
        raise PrtError(f"environment map not found: {path}")
    return lighting_from_sh(envmap_to_sh(load_envmap(path), order), n_lobes, source=str(path), window=window)


def hemisphere_visibility(order: int, below_horizon: str = "zero") -> np.ndarray:
    """``(C,)`` float32 unshadowed (unoccluded) visibility in the local frame, in the dataset's convention.

    ``below_horizon="zero"`` (docs/DESIGN.md): the SH of the upper-hemisphere indicator, only ``m = 0``
    terms, ``v_l0 = 2 pi int_0^1 y_l0(z) dz``. ``"one"`` (seed 003 eq. 1): the constant 1, ``sqrt(4 pi) e_0``.
    """
    from prt_torch.sh.basis import sh_basis

    if below_horizon not in BELOW_HORIZON:
        raise PrtError(f"below_horizon must be one of {list(BELOW_HORIZON)}, got {below_horizon!r}")
    if below_horizon == "one":
        out1 = np.zeros(order * order, dtype=np.float32)
        out1[0] = np.sqrt(4 * np.pi)
        return out1

    z, wz = np.polynomial.legendre.leggauss(max(order, 2))
    z = 0.5 * (z + 1.0)
    wz = 0.5 * wz
    dirs = np.stack([np.sqrt(1 - z * z), np.zeros_like(z), z], axis=-1)
    y = sh_basis(dirs, order)  # (N, C)
    out = 2 * np.pi * (wz @ y)
    m = np.concatenate([np.arange(-l, l + 1) for l in range(order)])
    out[m != 0] = 0.0
    return out.astype(np.float32)

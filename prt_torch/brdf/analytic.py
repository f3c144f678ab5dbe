"""Isotropic analytic BRDFs in the local frame (z = normal), physically normalised, with an RGB tint.

Every model is ``f(wi, wo) = tint * s(wi, wo)`` with a scalar *shape* ``s`` whose directional albedo
``int s(wi, wo) cos(theta_i) dwi`` is at most 1 (for ``kd + ks <= 1``); ``s = 0`` when either direction
is below the horizon (``z <= 0``). All models are reciprocal (``s(wi, wo) = s(wo, wi)``).

* :class:`Lambert`: ``1 / pi``.
* :class:`Phong` (normalised modified Phong, Lafortune & Willems 1994):
  ``kd/pi + ks (e + 2)/(2 pi) max(r(wo) . wi, 0)^e`` with ``r(wo) = (-x, -y, z)`` the mirror direction;
  albedo exactly ``kd + ks`` at normal incidence.
* :class:`BlinnPhong` (normalised Blinn-Phong): ``kd/pi + ks k(e) (n . h)^e``, ``h = (wi + wo)/|wi + wo|``,
  ``k(e)`` in closed form such that the albedo is exactly ``kd + ks`` at normal incidence (the usual
  ``(e + 8)/(8 pi)`` is its large-``e`` approximation and slightly exceeds 1).
* :class:`CookTorrance` (microfacet, Walter et al. 2007): ``kd/pi + ks D G F / (4 cos_i cos_o)`` with the
  GGX distribution ``D = a^2 / (pi ((n.h)^2 (a^2 - 1) + 1)^2)``, the separable Smith GGX shadowing
  ``G = G1(wi) G1(wo)``, ``G1(v) = 2 cos / (cos + sqrt(a^2 + (1 - a^2) cos^2))`` and Schlick's Fresnel
  ``F = F0 + (1 - F0)(1 - wi.h)^5``; ``a`` = roughness^2 (perceptual roughness).
* :class:`Ward` (isotropic Ward 1992): ``kd/pi + ks exp(-tan^2(theta_h)/a^2) / (4 pi a^2 sqrt(cos_i cos_o))``.

numpy only (float64); inputs are ``(N, 3)`` unit directions, outputs ``(N,)`` (shape) or ``(N, 3)`` (RGB).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from prt_torch.errors import PrtError
from prt_torch.sh.basis import check_directions


def _tint(t: object) -> np.ndarray:
    a = np.asarray(t, dtype=np.float64)
    if a.ndim == 0:
        a = np.full(3, float(a))
    if a.shape != (3,) or not np.isfinite(a).all() or (a < 0).any():
        raise PrtError(f"BRDF tint must be a non-negative finite RGB triple, got {t!r}")
    return a


def check_pair(wi: np.ndarray, wo: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Validate ``(N, 3)`` unit direction arrays of equal shape; returns float64 copies."""
    for name, d in (("wi", wi), ("wo", wo)):
        if not isinstance(d, np.ndarray) or d.ndim != 2 or d.shape[1] != 3:
            raise PrtError(f"BRDF {name} must be a (N, 3) numpy array, got "
                           f"{getattr(d, 'shape', type(d).__name__)}")
        check_directions(d, f"BRDF {name}")
    if wi.shape != wo.shape:
        raise PrtError(f"BRDF wi and wo must have the same shape, got {wi.shape} and {wo.shape}")
    return wi.astype(np.float64), wo.astype(np.float64)


def _check_weights(kd: float, ks: float) -> None:
    if not (np.isfinite(kd) and np.isfinite(ks)) or kd < 0 or ks < 0 or kd + ks > 1 + 1e-12:
        raise PrtError(f"BRDF weights need kd, ks >= 0 and kd + ks <= 1 (energy), got kd={kd}, ks={ks}")


def _check_exponent(exponent: float, what: str) -> None:
    if not np.isfinite(exponent) or exponent < 0:
        raise PrtError(f"{what} exponent must be finite and >= 0, got {exponent}")


def _half(wi: np.ndarray, wo: np.ndarray) -> np.ndarray:
    h = wi + wo
    n = np.linalg.norm(h, axis=1, keepdims=True)
    return h / np.where(n > 0, n, 1.0)


@dataclass
class BRDF:
    """Base class: isotropic BRDF ``f = tint * shape(wi, wo)`` in the local frame (z = normal)."""

    tint: np.ndarray = field(default_factory=lambda: np.ones(3))
    name: str = "brdf"

    def __post_init__(self) -> None:
        self.tint = _tint(self.tint)

    def _shape(self, wi: np.ndarray, wo: np.ndarray) -> np.ndarray:  # pragma: no cover - abstract
        raise NotImplementedError

    def shape(self, wi: np.ndarray, wo: np.ndarray) -> np.ndarray:
        """Scalar shape ``s(wi, wo)``, ``(N,)`` float64; 0 where ``wi.z <= 0`` or ``wo.z <= 0``."""
        wi, wo = check_pair(wi, wo)
        up = (wi[:, 2] > 0) & (wo[:, 2] > 0)
        out = np.zeros(len(wi))
        if up.any():
            out[up] = self._shape(wi[up], wo[up])
        return out

    def __call__(self, wi: np.ndarray, wo: np.ndarray) -> np.ndarray:
        """RGB BRDF values ``(N, 3)`` float64 for ``(N, 3)`` local unit directions."""
        return self.shape(wi, wo)[:, None] * self.tint[None, :]

    def cosine_weighted(self, wi: np.ndarray, wo: np.ndarray) -> np.ndarray:
        """``f~ = s(wi, wo) max(wi.z, 0)`` (scalar shape, no tint), ``(N,)`` float64."""
        return self.shape(wi, wo) * np.maximum(wi[:, 2], 0.0)


@dataclass
class Lambert(BRDF):
    """Lambertian ``tint / pi``."""

    name: str = "lambert"

    def _shape(self, wi: np.ndarray, wo: np.ndarray) -> np.ndarray:
        return np.full(len(wi), 1.0 / math.pi)


@dataclass
class Phong(BRDF):
    """Normalised modified Phong: ``kd/pi + ks (e+2)/(2 pi) max(r(wo).wi, 0)^e``."""

    exponent: float = 16.0
    kd: float = 0.0
    ks: float = 1.0
    name: str = "phong"

    def __post_init__(self) -> None:
        super().__post_init__()
        _check_weights(self.kd, self.ks)
        _check_exponent(self.exponent, "Phong")

    def _shape(self, wi: np.ndarray, wo: np.ndarray) -> np.ndarray:
        c = np.maximum(-wi[:, 0] * wo[:, 0] - wi[:, 1] * wo[:, 1] + wi[:, 2] * wo[:, 2], 0.0)
        return self.kd / math.pi + self.ks * (self.exponent + 2) / (2 * math.pi) * c**self.exponent


@dataclass
class BlinnPhong(BRDF):
    """Normalised Blinn-Phong: ``kd/pi + ks k(e) (n.h)^e`` (see :attr:`norm`)."""

    exponent: float = 32.0
    kd: float = 0.0
    ks: float = 1.0
    name: str = "blinn"

    def __post_init__(self) -> None:
        super().__post_init__()
        _check_weights(self.kd, self.ks)
        _check_exponent(self.exponent, "Blinn-Phong")

    @property
    def norm(self) -> float:
        """Normalisation ``k(e)``: the lobe ``k (n.h)^e`` has albedo exactly 1 at normal incidence.

        With ``wo = n``, ``theta_h = theta_i / 2`` and ``x = cos theta_h``:
        ``1 = 8 pi k int_{1/sqrt2}^1 x^{e+1} (2x^2 - 1) dx = 8 pi k [2x^{e+4}/(e+4) - x^{e+2}/(e+2)]``;
        ``k ~ (e + 8)/(8 pi)`` for large ``e`` (the usual approximation, which exceeds 1 by ~3% at e = 40).
        """
        e = self.exponent

        def prim(x: float) -> float:
            return 2 * x ** (e + 4) / (e + 4) - x ** (e + 2) / (e + 2)

        return 1.0 / (8 * math.pi * (prim(1.0) - prim(math.sqrt(0.5))))

    def _shape(self, wi: np.ndarray, wo: np.ndarray) -> np.ndarray:
        nh = np.maximum(_half(wi, wo)[:, 2], 0.0)
        return self.kd / math.pi + self.ks * self.norm * nh**self.exponent


def ggx_d(cos_h: np.ndarray, alpha: float) -> np.ndarray:
    """GGX normal distribution ``D(h)`` (``int D cos(theta_h) dh = 1``)."""
    a2 = alpha * alpha
    return a2 / (math.pi * (cos_h * cos_h * (a2 - 1) + 1) ** 2)


def smith_ggx_g1(cos_v: np.ndarray, alpha: float) -> np.ndarray:
    """Smith GGX masking ``G1(v) = 2 cos / (cos + sqrt(a^2 + (1 - a^2) cos^2))``."""
    a2 = alpha * alpha
    return 2 * cos_v / (cos_v + np.sqrt(a2 + (1 - a2) * cos_v * cos_v))


@dataclass
class CookTorrance(BRDF):
    """Cook-Torrance microfacet BRDF with GGX ``D``, separable Smith ``G``, Schlick ``F`` (+ optional Lambert)."""

    roughness: float = 0.5
    f0: float = 0.04
    kd: float = 0.0
    ks: float = 1.0
    name: str = "ggx"

    def __post_init__(self) -> None:
        super().__post_init__()
        _check_weights(self.kd, self.ks)
        if not (0.02 <= self.roughness <= 1.0):
            raise PrtError(f"Cook-Torrance roughness must be in [0.02, 1], got {self.roughness}")
        if not (0.0 <= self.f0 <= 1.0):
            raise PrtError(f"Cook-Torrance f0 must be in [0, 1], got {self.f0}")

    @property
    def alpha(self) -> float:
        """GGX width ``a = roughness^2``."""
        return self.roughness**2

    def _shape(self, wi: np.ndarray, wo: np.ndarray) -> np.ndarray:
        h = _half(wi, wo)
        ci, co = wi[:, 2], wo[:, 2]
        d = ggx_d(np.maximum(h[:, 2], 0.0), self.alpha)
        g = smith_ggx_g1(ci, self.alpha) * smith_ggx_g1(co, self.alpha)
        f = self.f0 + (1 - self.f0) * (1 - np.clip((wi * h).sum(1), 0.0, 1.0)) ** 5
        return self.kd / math.pi + self.ks * d * g * f / (4 * ci * co)


@dataclass
class Ward(BRDF):
    """Isotropic Ward: ``kd/pi + ks exp(-tan^2 theta_h / a^2) / (4 pi a^2 sqrt(cos_i cos_o))``."""

    alpha: float = 0.3
    kd: float = 0.0
    ks: float = 1.0
    name: str = "ward"

    def __post_init__(self) -> None:
        super().__post_init__()
        _check_weights(self.kd, self.ks)
        if not (0.01 <= self.alpha <= 1.0):
            raise PrtError(f"Ward alpha must be in [0.01, 1], got {self.alpha}")

    def _shape(self, wi: np.ndarray, wo: np.ndarray) -> np.ndarray:
        h = _half(wi, wo)
        c2 = np.maximum(h[:, 2], 1e-12) ** 2
        tan2 = (1 - c2) / c2
        a2 = self.alpha**2
        spec = np.exp(-tan2 / a2) / (4 * math.pi * a2 * np.sqrt(wi[:, 2] * wo[:, 2]))
        return self.kd / math.pi + self.ks * spec

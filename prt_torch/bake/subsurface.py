"""Subsurface exit-radiance transfer: single scattering + the dipole diffusion approximation (Jensen et al.
2001; seed 001 sec. 5 / Fig. 3 follow Wang et al. 2005 for the precomputation).

Units: scattering coefficients in 1/mm; world positions are scaled by ``scale`` (mm per world unit).
Reduced extinction ``sigma_t' = sigma_a + sigma_s'``, reduced albedo ``a' = sigma_s' / sigma_t'``, effective
transport coefficient ``sigma_tr = sqrt(3 sigma_a sigma_t')``, diffuse Fresnel reflectance
``F_dr = -1.440/eta^2 + 0.710/eta + 0.668 + 0.0636 eta``, ``A = (1 + F_dr) / (1 - F_dr)``, real and virtual
sources at depths ``z_r = 1/sigma_t'`` and ``z_v = z_r (1 + 4A/3)``; with ``d_{r,v} = sqrt(r^2 + z_{r,v}^2)``::

    Rd(r) = a'/(4 pi) sum_{z, d in (z_r, d_r), (z_v, d_v)} z (sigma_tr d + 1) e^{-sigma_tr d} / d^3

whose integral over the plane is ``R_d = a'/2 (1 + e^{-4/3 A sqrt(3(1-a'))}) e^{-sqrt(3(1-a'))}`` and over a disk
of radius ``rho`` ``a'/2 sum_{z in (z_r, z_v)} (e^{-sigma_tr z} - z e^{-sigma_tr d(rho)} / d(rho))``.

**Multiple scattering** (Jensen's ``S_d = F_t(w_i) Rd F_t(w_o) / pi``, both directional Fresnel transmittances
replaced by their hemispherical average ``1 - F_dr`` so that the exit radiance is isotropic): the incident
irradiance at ``x_i`` is ``pi L . t(x_i)`` with ``t`` the bake's cosine-weighted transfer (global frame,
including its interreflection bounces), so the exit radiance at ``x_o`` is ``L . s_ms(x_o)`` with::

    s_ms(x_o) = (1 - F_dr)^2 sum_i K_oi t(x_i),   K_oi = A_i Rd(|x_o - x_i|)   (i != o),   K_oo = int_disk(A_o) Rd

``A_i`` the vertex areas (a third of the adjacent triangles'), the self term the disk integral over the vertex's
own area (so a mesh coarser than the diffusion length still yields ``R_d``); ``K`` is a sparse matrix from a
scipy ``cKDTree`` pair search cut off at ``cutoff / sigma_tr`` (``cutoff`` diffusion lengths; the kernel decays as
``e^{-sigma_tr r}``).

**Single scattering** (Hanrahan-Krueger 1993 for a locally flat semi-infinite medium, isotropic phase
``1/(4 pi)``, reduced albedo by the similarity relation): a ray entering with cosine ``mu`` (refracted cosine
``mu_t = sqrt(1 - (1 - mu^2)/eta^2)``) and leaving with refracted cosine ``mu_o`` contributes
``a' (1 - F_dr)^2 / (4 pi eta^2) mu / (mu_t + mu_o)`` per unit incident radiance and solid angle; its cosine-
weighted mean over exit directions ``2 int_0^1 (.) mu_o d mu_o`` makes it isotropic::

    s_ss(x) = int V(w) w1(n.w) y(w) dw,  w1(mu) = a' (1 - F_dr)^2 / (4 pi eta^2) 2 mu (1 - mu_t ln(1 + 1/mu_t))

estimated with the bake's rays (the visibility of the same traced rays). ``subsurface = s_ss + s_ms``: the
subsurface exit radiance is ``L . subsurface`` (global SH, order ``transfer_order``), one scalar channel
(per-RGB coefficients need one store each).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields
from typing import Any

import numpy as np
import scipy.sparse as sp
from scipy.spatial import cKDTree

from prt_torch.bake.trace import RayHits, RaySet
from prt_torch.bake.transfer import occlusion_transfer
from prt_torch.errors import PrtError, check
from prt_torch.shapes import check_shape


@dataclass(frozen=True)
class DipoleParams:
    """Dipole material: ``sigma_a``, ``sigma_s_prime`` (reduced scattering) in 1/mm, relative index ``eta``,
    ``scale`` mm per world unit, kernel ``cutoff`` in diffusion lengths ``1/sigma_tr``, ``single`` scattering on.

    Defaults: Jensen et al. 2001's skin1, green channel.
    """

    sigma_a: float = 0.17
    sigma_s_prime: float = 0.88
    eta: float = 1.3
    scale: float = 1000.0
    cutoff: float = 6.0
    single: bool = True

    def __post_init__(self) -> None:
        for name in ("sigma_a", "sigma_s_prime", "scale", "cutoff"):
            value = getattr(self, name)
            check(isinstance(value, int | float) and math.isfinite(value) and value > 0,
                  f"subsurface {name} must be a finite number > 0, got {value!r}")
        check(isinstance(self.eta, int | float) and math.isfinite(self.eta) and 1.0 <= self.eta <= 3.0,
              f"subsurface eta must be in [1, 3], got {self.eta!r}")

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> DipoleParams:
        """From a ``SubsurfaceConfig`` dump (unknown keys are a one-line error)."""
        names = {f.name for f in fields(cls)}
        extra = sorted(set(d) - names)
        check(not extra, f"unknown subsurface parameter(s): {', '.join(extra)}")
        return cls(**d)

    @property
    def sigma_t_prime(self) -> float:
        return self.sigma_a + self.sigma_s_prime

    @property
    def alpha_prime(self) -> float:
        return self.sigma_s_prime / self.sigma_t_prime

    @property
    def sigma_tr(self) -> float:
        return math.sqrt(3.0 * self.sigma_a * self.sigma_t_prime)

    @property
    def F_dr(self) -> float:
        return diffuse_fresnel_reflectance(self.eta)

    @property
    def A(self) -> float:
        return (1.0 + self.F_dr) / (1.0 - self.F_dr)

    @property
    def z_r(self) -> float:
        return 1.0 / self.sigma_t_prime

    @property
    def z_v(self) -> float:
        return self.z_r * (1.0 + 4.0 * self.A / 3.0)

    @property
    def radius_mm(self) -> float:
        """Kernel cutoff radius in mm: ``cutoff / sigma_tr``."""
        return self.cutoff / self.sigma_tr


def diffuse_fresnel_reflectance(eta: float) -> float:
    """``F_dr(eta)``: the rational fit of Jensen et al. 2001 (Egan & Hilgeman)."""
    check(math.isfinite(eta) and eta >= 1.0, f"relative index of refraction must be >= 1, got {eta!r}")
    return -1.440 / eta**2 + 0.710 / eta + 0.668 + 0.0636 * eta


def dipole_Rd(r: np.ndarray | float, sigma_a: float, sigma_s_prime: float, eta: float) -> np.ndarray:
    """Jensen 2001 dipole diffuse reflectance ``Rd(r)`` (1/mm^2) at distances ``r`` (mm, >= 0); float64."""
    p = DipoleParams(sigma_a=sigma_a, sigma_s_prime=sigma_s_prime, eta=eta)
    r = np.asarray(r, dtype=np.float64)
    check(bool(np.isfinite(r).all()) and bool((r >= 0).all()), "dipole distances must be finite and >= 0")
    return _rd(r, p)


def _rd(r: np.ndarray, p: DipoleParams) -> np.ndarray:
    s = p.sigma_tr
    out = np.zeros_like(r, dtype=np.float64)
    for z in (p.z_r, p.z_v):
        d = np.sqrt(r * r + z * z)
        out += z * (s * d + 1.0) * np.exp(-s * d) / d**3
    return out * (p.alpha_prime / (4.0 * math.pi))


def dipole_disk(rho: np.ndarray | float, p: DipoleParams) -> np.ndarray:
    """``int_{|x| < rho} Rd(|x|) dA`` in closed form (dimensionless), float64."""
    rho = np.asarray(rho, dtype=np.float64)
    s = p.sigma_tr
    out = np.zeros_like(rho)
    for z in (p.z_r, p.z_v):
        d = np.sqrt(rho * rho + z * z)
        out += math.exp(-s * z) - z * np.exp(-s * d) / d
    return out * (p.alpha_prime / 2.0)


def dipole_total(p: DipoleParams) -> float:
    """Total diffuse reflectance ``R_d = int Rd dA`` over the plane (the ``rho -> inf`` disk integral)."""
    return float(p.alpha_prime / 2.0 * (math.exp(-p.sigma_tr * p.z_r) + math.exp(-p.sigma_tr * p.z_v)))


def vertex_areas(positions: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """``(V,)`` float64: a third of the area of every triangle touching each vertex (world units^2)."""
    positions = np.asarray(positions, dtype=np.float64)
    faces = np.asarray(faces)
    check_shape(positions, "V 3", name="positions")
    check_shape(faces, "T 3", name="faces")
    p = positions[faces]
    a = 0.5 * np.linalg.norm(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), axis=1)
    return np.bincount(faces.reshape(-1), weights=np.repeat(a / 3.0, 3), minlength=len(positions))


def dipole_kernel(positions: np.ndarray, areas: np.ndarray, p: DipoleParams) -> sp.csr_matrix:
    """Sparse ``(V, V)`` area-weighted dipole kernel ``K`` (see the module docstring), float64.

    ``K_oi = A_i Rd(|x_o - x_i|)`` for ``0 < |x_o - x_i| * scale < cutoff / sigma_tr`` (areas in mm^2), the
    diagonal the disk integral over ``A_o``. A scipy ``cKDTree`` pair search; no loop over vertices.
    """
    x = np.asarray(positions, dtype=np.float64) * p.scale
    a = np.asarray(areas, dtype=np.float64) * p.scale**2
    V = x.shape[0]
    check_shape(a, (V,), name="vertex areas")
    check(bool(np.isfinite(x).all()) and bool(np.isfinite(a).all()) and bool((a >= 0).all()),
          "subsurface positions and areas must be finite (areas >= 0)")
    pairs = cKDTree(x).query_pairs(p.radius_mm, output_type="ndarray")  # (P, 2), i < j
    i, j = pairs[:, 0], pairs[:, 1]
    rd = _rd(np.linalg.norm(x[i] - x[j], axis=1), p)
    diag = np.arange(V)
    rows = np.concatenate([i, j, diag])
    cols = np.concatenate([j, i, diag])
    vals = np.concatenate([rd * a[j], rd * a[i], dipole_disk(np.sqrt(a / math.pi), p)])
    return sp.coo_matrix((vals, (rows, cols)), shape=(V, V)).tocsr()


def single_scatter_weight(mu: np.ndarray, p: DipoleParams) -> np.ndarray:
    """``w1(mu)`` of the module docstring (per unit incident radiance and solid angle), float64."""
    mu = np.clip(np.asarray(mu, dtype=np.float64), 0.0, 1.0)
    mu_t = np.sqrt(1.0 - (1.0 - mu * mu) / p.eta**2)
    f = 2.0 * mu * (1.0 - mu_t * np.log1p(1.0 / mu_t))
    return p.alpha_prime * (1.0 - p.F_dr) ** 2 / (4.0 * math.pi * p.eta**2) * f


def single_scatter_transfer(frames: np.ndarray, rays: RaySet, occluded: np.ndarray, order: int,
                            p: DipoleParams) -> np.ndarray:
    """``s_ss (V, C)`` float32 (global frame) from the bake's rays and their occlusion ``(R, V)`` bool."""
    frames = np.asarray(frames)
    V = frames.shape[0]
    R = rays.n_rays
    check_shape(occluded, (R, V), name="ray occlusion")
    weight = (math.pi * single_scatter_weight(rays.cos, p)).astype(np.float32)  # direct_transfer scales by 2/R
    return occlusion_transfer(frames, rays.local, rays.phi, occluded, weight, order)


def subsurface_transfer(positions: np.ndarray, areas: np.ndarray, irradiance_transfer: np.ndarray,
                        params: DipoleParams, single: np.ndarray | None = None) -> np.ndarray:
    """Subsurface exit-radiance transfer ``(V, C)`` float32 (global frame): ``s_ms`` (+ ``single`` if given).

    Args:
        positions: ``(V, 3)`` posed vertex positions (world units).
        areas: ``(V,)`` vertex areas (world units^2, :func:`vertex_areas`).
        irradiance_transfer: ``(V, C)`` cosine-weighted transfer ``t`` (irradiance ``pi L . t``), global frame.
        params: the dipole material.
        single: optional ``(V, C)`` single-scattering transfer (:func:`single_scatter_transfer`).
    """
    if not isinstance(params, DipoleParams):
        raise PrtError(f"subsurface parameters must be DipoleParams, got {type(params).__name__}")
    t = np.asarray(irradiance_transfer)
    V = np.asarray(positions).shape[0]
    check_shape(t, (V, "C"), name="irradiance transfer")
    check(bool(np.isfinite(t).all()), "irradiance transfer contains NaN or Inf")
    K = dipole_kernel(positions, areas, params)
    out = (1.0 - params.F_dr) ** 2 * (K @ t.astype(np.float64))
    if single is not None:
        check(np.shape(single) == t.shape, f"single scattering must have shape {t.shape}, got {np.shape(single)}")
        out = out + single
    return out.astype(np.float32)


def frame_subsurface(positions: np.ndarray, frames: np.ndarray, faces: np.ndarray, rays: RaySet, hits: RayHits,
                     transfer: np.ndarray, params: DipoleParams) -> np.ndarray:
    """The bake's ``subsurface (V, C6)`` of one traced frame (same rays, hits and transfer)."""
    order = int(round(math.sqrt(transfer.shape[1])))
    single = single_scatter_transfer(frames, rays, hits.occluded, order, params) if params.single else None
    return subsurface_transfer(positions, vertex_areas(positions, faces), transfer, params, single)

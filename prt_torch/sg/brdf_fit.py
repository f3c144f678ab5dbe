"""Spherical-Gaussian fits of the project's analytic BRDFs (seed 004 sec. 4; Wang et al. 2009).

A BRDF times the incident cosine, seen as a function of the incident direction ``wi`` for a fixed normal
``n`` and view ``wo``, is approximated by a few SGs (``SG(v) = mu exp(lambda (v . p - 1))``):

* **cosine** ``max(n . wi, 0)`` ~ ``sum_j c_j exp(k_j (n . wi - 1))`` (1-3 lobes about ``n``; one lobe gives
  the familiar ``k ~ 2.13, c ~ 1.17``). The diffuse term ``kd / pi`` (and :class:`~prt_torch.brdf.Lambert`)
  is ``kd / pi`` times these lobes.
* **Phong** (the project's normalised *modified* Phong, reflection-based): ``max(r . wi, 0)^e`` with
  ``r = 2 (n . wo) n - wo`` is fitted directly in ``wi`` about ``r``; amplitude ``ks (e + 2)/(2 pi)``, the
  cosine taken at the lobe axis (``n . r = n . wo``).
* **microfacet** (:class:`~prt_torch.brdf.BlinnPhong`, :class:`~prt_torch.brdf.CookTorrance` with GGX,
  :class:`~prt_torch.brdf.Ward`): the normal distribution ``D(n . h)`` is fitted in the half-vector domain
  about ``n`` (``D ~ sum_j mu_j exp(lambda_j (n . h - 1))``) and each lobe is *spherically warped* to the
  view (Wang et al. 2009): axis ``r = 2 (n . wo) n - wo`` (the mirror direction, where ``h = n``),
  sharpness ``lambda_j / (4 |n . wo|)`` (the Jacobian ``dwi/dh = 4 |h . wo|``), amplitude ``mu_j`` times the
  remaining factors of the BRDF and the cosine evaluated at the axis (``wi = r``, so ``cos_i = cos_o``):
  Blinn-Phong ``ks k(e) cos_o``; Cook-Torrance ``ks G1(cos_o)^2 F(cos_o) / 4``; Ward ``ks / (4 pi a^2)``.
* the variation of the cosine across a wide specular lobe: by default (``SGBRDF.cosine_product``) each
  specular lobe is multiplied by the one-lobe cosine SG about ``n`` (an SG product), rescaled so that the
  value at the lobe axis is unchanged; this halves the error at 60-75 degree views for Phong, Blinn and Ward.

Every profile fit is a small variable-projection least squares (``scipy.optimize.least_squares`` over the
log-sharpnesses, the amplitudes by linear least squares) in ``L2`` of the solid angle, on composite
Gauss-Legendre nodes in the angle that resolve the lobe. :func:`fit_brdf_sg` returns an :class:`SGBRDF`
(swappable at run time: a shader takes any of them) whose :meth:`SGBRDF.view_lobes` gives, for batches of
normals and views, the ``(axis, sharpness, amplitude)`` tensors for :func:`prt_torch.sg.algebra.sg_triple`,
and whose ``rel_error`` reports the relative L2 error of the whole SG BRDF x cosine against the analytic
BRDF over the upper hemisphere of ``wi``, per view elevation.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import torch
from scipy.optimize import least_squares

from prt_torch.brdf.analytic import BRDF, BlinnPhong, CookTorrance, Lambert, Phong, Ward, ggx_d
from prt_torch.brdf.factor import hemisphere_rule
from prt_torch.errors import PrtError, check
from prt_torch.sg.algebra import sg_product
from prt_torch.shapes import check_shape

#: view elevations (degrees from the normal) at which :func:`fit_brdf_sg` reports the error
ERROR_VIEW_DEGREES: tuple[float, ...] = (0.0, 30.0, 60.0, 75.0)

#: smallest ``n . wo`` used by the warp (grazing views): caps the warped sharpness at ``lambda / 4e-3``
_MIN_COS_O = 1e-3


@dataclass(frozen=True)
class ProfileFit:
    """SG fit of a rotationally symmetric profile ``d(c)``, ``c = cos`` of the angle to the lobe axis.

    ``d(c) ~ sum_j amplitude_j exp(sharpness_j (c - 1))`` for ``c`` in ``[c_min, 1]``.

    Attributes:
        sharpness: ``(J,)`` float64, > 0.
        amplitude: ``(J,)`` float64.
        rel_error: relative L2 error (solid-angle measure) of the fit over the profile's domain.
    """

    sharpness: np.ndarray
    amplitude: np.ndarray
    rel_error: float

    def __call__(self, c: np.ndarray) -> np.ndarray:
        """The fitted profile at cosines ``c`` (any shape)."""
        c = np.asarray(c, dtype=np.float64)
        return (self.amplitude * np.exp(self.sharpness * (c[..., None] - 1))).sum(-1)


def _profile_nodes(profile: Callable[[np.ndarray], np.ndarray], c_min: float,
                   n: int = 96) -> tuple[np.ndarray, np.ndarray]:
    """Composite Gauss-Legendre nodes in the angle ``t`` on ``[0, acos(c_min)]``: cosines ``(M,)`` and solid-angle
    weights ``2 pi sin t dt`` ``(M,)``; the first panel ends where the profile falls to 1e-4 of its peak."""
    t_max = math.acos(c_min)
    peak = float(profile(np.array([1.0]))[0])
    lo, hi = 0.0, t_max
    for _ in range(60):  # bisection for the 1e-4 width (profiles here decrease monotonically)
        mid = 0.5 * (lo + hi)
        if float(profile(np.array([math.cos(mid)]))[0]) > 1e-4 * peak:
            lo = mid
        else:
            hi = mid
    edges = sorted({0.0, min(hi, t_max), min(3 * hi, t_max), t_max})
    x, w = np.polynomial.legendre.leggauss(n)
    ts, ws = [], []
    for a, b in zip(edges[:-1], edges[1:], strict=True):
        if b - a > 1e-12:
            ts.append(0.5 * (b - a) * x + 0.5 * (a + b))
            ws.append(0.5 * (b - a) * w)
    t, wt = np.concatenate(ts), np.concatenate(ws)
    return np.cos(t), 2 * math.pi * np.sin(t) * wt


def fit_profile_sg(profile: Callable[[np.ndarray], np.ndarray], n_lobes: int = 1, c_min: float = 0.0) -> ProfileFit:
    """Fit ``n_lobes`` SGs (common axis) to a decreasing profile ``d(c)`` on ``c in [c_min, 1]``.

    Least squares in ``L2`` of the solid angle; variable projection: ``scipy.optimize.least_squares`` over
    ``log lambda_j``, amplitudes by linear least squares at each step. Start: the half-maximum sharpness
    ``log 2 / (1 - c_half)`` spread by factors of 4 across the lobes.
    """
    check(isinstance(n_lobes, int) and 1 <= n_lobes <= 3, f"SG BRDF fits take 1..3 lobes, got {n_lobes!r}")
    check(-1.0 <= c_min < 1.0, f"profile domain start c_min must be in [-1, 1), got {c_min}")
    c, w = _profile_nodes(profile, c_min)
    d = np.asarray(profile(c), dtype=np.float64)
    check(bool(np.isfinite(d).all()), "BRDF profile has NaN or Inf values")
    sw = np.sqrt(w)
    norm = math.sqrt(float((w * d * d).sum()))
    check(norm > 0, "BRDF profile is zero: nothing to fit")
    peak = float(profile(np.array([1.0]))[0])
    lo, hi = 0.0, math.acos(c_min)
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if float(profile(np.array([math.cos(mid)]))[0]) > 0.5 * peak else (lo, mid)
    lam0 = math.log(2) / max(1 - math.cos(hi), 1e-12)

    def design(loglam: np.ndarray) -> np.ndarray:
        return np.exp(np.exp(loglam)[None, :] * (c[:, None] - 1)) * sw[:, None]

    def amps(loglam: np.ndarray) -> np.ndarray:
        return np.linalg.lstsq(design(loglam), sw * d, rcond=None)[0]

    def resid(loglam: np.ndarray) -> np.ndarray:
        return (design(loglam) @ amps(loglam) - sw * d) / norm

    x0 = np.log(lam0) + np.log(4.0) * (np.arange(n_lobes) - (n_lobes - 1) / 2)
    sol = least_squares(resid, x0, method="trf", x_scale=1.0, xtol=1e-12, ftol=1e-12, gtol=1e-12, max_nfev=400)
    lam = np.exp(sol.x)
    order = np.argsort(lam)
    lam = lam[order]
    mu = amps(np.log(lam))
    return ProfileFit(sharpness=lam, amplitude=mu, rel_error=float(np.linalg.norm(resid(np.log(lam)))))


@functools.cache
def cosine_fit(n_lobes: int = 1) -> ProfileFit:
    """SG fit of the clamped cosine ``max(c, 0)`` over the whole sphere (``c in [-1, 1]``), 1-3 lobes."""
    return fit_profile_sg(lambda c: np.maximum(c, 0.0), n_lobes, c_min=-1.0)


def _family(brdf: BRDF) -> str:
    if isinstance(brdf, Lambert):
        return "lambert"
    if isinstance(brdf, Phong):
        return "phong"
    if isinstance(brdf, BlinnPhong | CookTorrance | Ward):
        return "microfacet"
    raise PrtError(f"no SG fit for BRDF type {type(brdf).__name__}: expected Lambert, Phong, BlinnPhong, "
                   f"CookTorrance or Ward")


def _distribution(brdf: BRDF) -> tuple[Callable[[np.ndarray], np.ndarray], float]:
    """The specular profile ``d(c)`` to fit and its domain start ``c_min``."""
    if isinstance(brdf, Phong):
        e = brdf.exponent
        return (lambda c: np.maximum(c, 0.0) ** e), -1.0
    if isinstance(brdf, BlinnPhong):
        e = brdf.exponent
        return (lambda c: np.maximum(c, 0.0) ** e), 0.0
    if isinstance(brdf, CookTorrance):
        a = brdf.alpha
        return (lambda c: ggx_d(np.clip(c, 0.0, 1.0), a)), 0.0
    if isinstance(brdf, Ward):
        a2 = brdf.alpha**2

        def ward(c: np.ndarray) -> np.ndarray:
            c2 = np.maximum(c, 1e-12) ** 2
            return np.where(c > 0, np.exp(-(1 - c2) / c2 / a2), 0.0)

        return ward, 0.0
    raise PrtError(f"BRDF {type(brdf).__name__} has no specular lobe")  # pragma: no cover


@dataclass
class SGBRDF:
    """An analytic BRDF x cosine as SGs, warped per (normal, view) by :meth:`view_lobes`.

    Attributes:
        brdf: the analytic BRDF (numpy; the reference).
        family: ``"lambert"``, ``"phong"`` or ``"microfacet"``.
        cosine: the clamped-cosine lobes (diffuse term), :func:`cosine_fit`.
        specular: the specular profile lobes (None for Lambert or ``ks = 0``).
        rel_error: view elevation in degrees -> relative L2 error of the SG BRDF x cosine vs the analytic one
            over the upper hemisphere of ``wi`` (filled by :func:`fit_brdf_sg`).
    """

    brdf: BRDF
    family: str
    cosine: ProfileFit
    specular: ProfileFit | None
    rel_error: dict[float, float] = field(default_factory=dict)
    #: multiply specular lobes by the cosine SG (renormalised at the axis) instead of a constant cosine
    cosine_product: bool = True

    @property
    def name(self) -> str:
        return self.brdf.name

    @property
    def kd(self) -> float:
        return 1.0 if self.family == "lambert" else float(self.brdf.kd)  # type: ignore[attr-defined]

    @property
    def ks(self) -> float:
        return 0.0 if self.family == "lambert" else float(self.brdf.ks)  # type: ignore[attr-defined]

    @property
    def n_lobes(self) -> int:
        """Lobes per (normal, view): diffuse (if ``kd > 0``) + specular."""
        return (len(self.cosine.sharpness) if self.kd > 0 else 0) + \
            (len(self.specular.sharpness) if self.specular is not None else 0)

    def _spec_scale(self, cos_o: torch.Tensor) -> torch.Tensor:
        """Factor multiplying the fitted profile at the lobe axis (``cos_i = cos_o``), ``(...)``."""
        b = self.brdf
        if isinstance(b, Phong):
            return b.ks * (b.exponent + 2) / (2 * math.pi) * cos_o
        if isinstance(b, BlinnPhong):
            return b.ks * b.norm * cos_o
        if isinstance(b, CookTorrance):
            a2 = b.alpha**2
            g1 = 2 * cos_o / (cos_o + torch.sqrt(a2 + (1 - a2) * cos_o * cos_o))
            f = b.f0 + (1 - b.f0) * (1 - cos_o) ** 5
            return b.ks * g1 * g1 * f / (4 * cos_o)
        if isinstance(b, Ward):
            return b.ks / (4 * math.pi * b.alpha**2) * torch.ones_like(cos_o)
        raise PrtError(f"BRDF {type(b).__name__} has no specular lobe")  # pragma: no cover

    def view_lobes(self, normal: torch.Tensor, view: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """SG lobes of ``f(wi, wo) max(n . wi, 0)`` as a function of ``wi``, for batches of normals and views.

        Args:
            normal: ``(..., 3)`` unit normals. view: ``(..., 3)`` unit directions toward the viewer (``wo``);
                same frame as the normals (world or local), broadcasting.

        Returns:
            ``axis (..., J, 3)``, ``sharpness (..., J)``, ``amplitude (..., J, 3)`` (RGB, tint included) with
            ``J = n_lobes``: diffuse lobes first (axis ``n``), then specular lobes (axis the mirror direction).
            Views below the horizon (``n . wo <= 0``) get zero specular amplitudes.
        """
        n = torch.as_tensor(normal)
        v = torch.as_tensor(view, dtype=n.dtype, device=n.device)
        check_shape(n, "... 3", name="view_lobes normals")
        check_shape(v, "... 3", name="view_lobes views")
        if not bool(torch.isfinite(n).all()) or not bool(torch.isfinite(v).all()):
            raise PrtError("view_lobes normals or views contain NaN or Inf")
        n, v = torch.broadcast_tensors(n, v)
        batch = n.shape[:-1]
        tint = torch.as_tensor(self.brdf.tint, dtype=n.dtype, device=n.device)
        axes, lams, amps = [], [], []
        if self.kd > 0:
            j = len(self.cosine.sharpness)
            axes.append(n.unsqueeze(-2).expand(*batch, j, 3))
            lams.append(torch.as_tensor(self.cosine.sharpness, dtype=n.dtype, device=n.device).expand(*batch, j))
            mu = torch.as_tensor(self.cosine.amplitude, dtype=n.dtype, device=n.device) * (self.kd / math.pi)
            amps.append((mu[:, None] * tint).expand(*batch, j, 3))
        if self.specular is not None:
            j = len(self.specular.sharpness)
            cos_o = (n * v).sum(-1)
            up = cos_o > 0
            co = cos_o.clamp(min=_MIN_COS_O)
            r = 2 * cos_o.unsqueeze(-1) * n - v
            r = r / r.norm(dim=-1, keepdim=True).clamp(min=1e-12)
            lam = torch.as_tensor(self.specular.sharpness, dtype=n.dtype, device=n.device)
            mu = torch.as_tensor(self.specular.amplitude, dtype=n.dtype, device=n.device)
            if self.family == "microfacet":
                lam = lam / (4 * co.unsqueeze(-1))
            else:
                lam = lam.expand(*batch, j)
            scale = torch.where(up, self._spec_scale(co), torch.zeros_like(co))
            mu = scale.unsqueeze(-1) * mu
            r = r.unsqueeze(-2).expand(*batch, j, 3)
            lam = lam.expand(*batch, j)
            if self.cosine_product:
                # the cosine varies across wide lobes: multiply by the 1-lobe cosine SG about n, rescaled so that
                # the product still equals the lobe value at its axis (where cos_i = cos_o)
                kc, mc = float(cosine_fit(1).sharpness[0]), float(cosine_fit(1).amplitude[0])
                pn, ln, mn = sg_product(r, lam, mu, n.unsqueeze(-2).expand_as(r), torch.full_like(lam, kc),
                                        torch.full_like(lam, mc))
                at_axis = mc * torch.exp(kc * (co - 1)).unsqueeze(-1)  # the cosine SG at the lobe axis
                r, lam, mu = pn, ln, mn / at_axis
            axes.append(r)
            lams.append(lam)
            amps.append(mu.unsqueeze(-1) * tint)
        return torch.cat(axes, -2), torch.cat(lams, -1), torch.cat(amps, -2)

    def eval(self, normal: torch.Tensor, view: torch.Tensor, wi: torch.Tensor) -> torch.Tensor:
        """The SG approximation of ``f(wi, wo) max(n . wi, 0)`` (RGB), ``(..., 3)``, broadcasting."""
        p, lam, mu = self.view_lobes(normal, view)
        wi = torch.as_tensor(wi, dtype=p.dtype, device=p.device)
        g = torch.exp(lam * ((wi.unsqueeze(-2) * p).sum(-1) - 1))
        return (g.unsqueeze(-1) * mu).sum(-2)


def brdf_sg_error(sg: SGBRDF, view_degrees: tuple[float, ...] = ERROR_VIEW_DEGREES,
                  n_theta: int = 64, n_phi: int = 128) -> dict[float, float]:
    """Relative L2 error of the SG BRDF x cosine vs the analytic ``s(wi, wo) max(wi.z, 0)`` (tint removed),
    over the upper hemisphere of ``wi`` (Gauss-Legendre x uniform-azimuth rule), per view elevation (degrees,
    view in the x-z plane, normal +z)."""
    dirs, w = hemisphere_rule(n_theta, n_phi)
    tint = np.where(sg.brdf.tint > 0, sg.brdf.tint, 1.0)
    out: dict[float, float] = {}
    for deg in view_degrees:
        t = math.radians(deg)
        wo = np.array([math.sin(t), 0.0, math.cos(t)])
        ref = sg.brdf.cosine_weighted(dirs, np.repeat(wo[None], len(dirs), 0))
        approx = sg.eval(torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64), torch.as_tensor(wo),
                         torch.as_tensor(dirs)).numpy()
        approx = (approx / tint).mean(-1)
        out[float(deg)] = float(np.sqrt((w * (approx - ref) ** 2).sum() / (w * ref * ref).sum()))
    return out


def fit_brdf_sg(brdf: BRDF, n_lobes: int = 1, diffuse_lobes: int | None = None,
                view_degrees: tuple[float, ...] = ERROR_VIEW_DEGREES) -> SGBRDF:
    """SG fit of an analytic BRDF (Lambert, Phong, BlinnPhong, CookTorrance/GGX, Ward).

    Args:
        brdf: a :mod:`prt_torch.brdf` analytic BRDF.
        n_lobes: 1..3 SGs for the specular lobe (and for Lambert's cosine).
        diffuse_lobes: 1..3 SGs for the clamped cosine of the diffuse term ``kd / pi`` (default ``n_lobes``).
        view_degrees: view elevations at which ``rel_error`` is measured.

    Returns:
        an :class:`SGBRDF`; ``rel_error`` maps each view elevation to the relative L2 error vs the analytic BRDF.
    """
    family = _family(brdf)
    diffuse_lobes = n_lobes if diffuse_lobes is None else diffuse_lobes
    check(isinstance(n_lobes, int) and 1 <= n_lobes <= 3, f"SG BRDF fits take 1..3 lobes, got {n_lobes!r}")
    check(isinstance(diffuse_lobes, int) and 1 <= diffuse_lobes <= 3,
          f"SG BRDF diffuse fits take 1..3 lobes, got {diffuse_lobes!r}")
    if family == "lambert":
        sg = SGBRDF(brdf, family, cosine_fit(n_lobes), None)
    else:
        spec = None
        if brdf.ks > 0:  # type: ignore[attr-defined]
            prof, c_min = _distribution(brdf)
            spec = fit_profile_sg(prof, n_lobes, c_min)
        sg = SGBRDF(brdf, family, cosine_fit(diffuse_lobes), spec)
    sg.rel_error = brdf_sg_error(sg, view_degrees)
    return sg


def builtin_sg_brdf(name: str, n_lobes: int = 1) -> SGBRDF:
    """SG fit of a catalogue BRDF by name (``lambert``, ``phong``, ``blinn``, ``ggx``, ``ward``)."""
    from prt_torch.brdf.rpo import builtin_brdf

    return fit_brdf_sg(builtin_brdf(name), n_lobes)

"""Spherical-Gaussian algebra (seed 004, eq. 3-4; Tsai & Shih 2006; Wang et al. 2009), in torch.

An SG is ``G(v) = mu exp(lambda (v . p - 1))`` with unit axis ``p``, sharpness ``lambda > 0`` and amplitude
``mu``. Every function here takes lobes as separate tensors and BROADCASTS:

* axes ``p``: ``(..., 3)``; sharpness ``lambda``: ``(...)``;
* amplitudes ``mu``: ``(...)`` (scalar lobes) or ``(..., C)`` (e.g. RGB, ``C = 3``). An amplitude is taken
  to carry a trailing channel axis exactly when it has one more dimension than its sharpness.

Batch shapes broadcast by the usual torch rules (e.g. vertices ``(V, 1, 1, 1)`` x light lobes
``(1, L, 1, 1)`` x BRDF lobes ``(1, 1, B, 1)`` x visibility cones ``(1, 1, 1, S)``); results have the
broadcast batch shape plus the channel axis where any amplitude has one. Nothing is summed unless the
docstring says so. Formulas (``r = |sum_i lambda_i p_i|``)::

    integral     int G = 2 pi mu / lambda (1 - exp(-2 lambda))
    product      G1 G2 = SG(p = (l1 p1 + l2 p2) / r, lambda = r, mu = m1 m2 exp(r - l1 - l2))
    inner        int G1 G2 = 4 pi m1 m2 sinh(r) / (r exp(l1 + l2))
    triple       int G1 G2 G3 = 4 pi m1 m2 m3 sinh(r) / (r exp(l1 + l2 + l3))      (eq. 4)

all evaluated in the overflow-free form ``2 pi mu exp(r - sum l) (1 - exp(-2 r)) / r`` (``-> 4 pi`` as
``r -> 0``) with ``r - sum l`` computed without cancellation from the pairwise ``|p_i - p_j|^2``: float32
stays within ~1e-4 of float64 for sharpness up to ~1e5 (very specular lobes, narrow cones).
"""

from __future__ import annotations

import math
from typing import Union

import torch

from prt_torch.errors import PrtError, check
from prt_torch.shapes import check_shape

#: below this ``r`` the ``(1 - exp(-2 r)) / r`` factor uses its Taylor series ``2 - 2 r + 4/3 r^2``
_SMALL_R = 1e-4

#: an SG given as a tuple ``(axis (..., 3), sharpness (...), amplitude (...) or (..., C))``, or an SGLobes
SGLike = Union[tuple[torch.Tensor, torch.Tensor, torch.Tensor], "SGLobes"]  # noqa: F821


def _tensor(x: object, name: str, like: torch.Tensor | None = None) -> torch.Tensor:
    if not isinstance(x, torch.Tensor):
        try:
            x = torch.as_tensor(x, dtype=like.dtype if like is not None else torch.float64,
                                device=like.device if like is not None else None)
        except (TypeError, ValueError, RuntimeError) as exc:
            raise PrtError(f"SG {name} must be a numeric tensor: {exc}") from None
    check(x.is_floating_point(), f"SG {name} must be floating point, got {x.dtype}")
    return x


def _check_lobe(p: torch.Tensor, lam: torch.Tensor, mu: torch.Tensor, tag: str = "") -> None:
    check_shape(p, "... 3", name=f"SG{tag} axis")
    check(mu.ndim in (lam.ndim, lam.ndim + 1), f"SG{tag} amplitude must have the sharpness shape {tuple(lam.shape)} "
          f"or that plus a channel axis, got {tuple(mu.shape)}")
    if not bool(torch.isfinite(lam).all()) or not bool(torch.isfinite(p).all()) or not bool(torch.isfinite(mu).all()):
        raise PrtError(f"SG{tag} axis, sharpness or amplitude contains NaN or Inf")
    if lam.numel() and not bool((lam > 0).all()):
        raise PrtError(f"SG{tag} sharpness (lambda) must be > 0, got min {float(lam.min()):.6g}")


def _unpack(sg: SGLike, tag: str) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    if hasattr(sg, "as_tuple"):
        return sg.as_tuple()  # type: ignore[union-attr]
    if not (isinstance(sg, tuple | list) and len(sg) == 3):
        raise PrtError(f"SG{tag} must be an SGLobes or an (axis, sharpness, amplitude) tuple, got {type(sg).__name__}")
    p = _tensor(sg[0], "axis")
    return p, _tensor(sg[1], "sharpness", p), _tensor(sg[2], "amplitude", p)


def _chan(mu: torch.Tensor, lam: torch.Tensor) -> torch.Tensor:
    """Amplitude with an explicit trailing channel axis (size 1 for scalar lobes)."""
    return mu if mu.ndim == lam.ndim + 1 else mu.unsqueeze(-1)


def _sinhc_scaled(r: torch.Tensor, r_minus_s: torch.Tensor) -> torch.Tensor:
    """``4 pi sinh(r) / (r exp(s))`` without overflow (``r <= s``): ``2 pi e^(r - s)(1 - e^-2r)/r``."""
    small = r < _SMALL_R
    rs = torch.where(small, torch.ones_like(r), r)
    f = torch.where(small, 2 - 2 * r + (4.0 / 3.0) * r * r, -torch.expm1(-2 * rs) / rs)
    return 2 * math.pi * torch.exp(r_minus_s) * f


def _norm_and_deficit(lobes: list[tuple[torch.Tensor, torch.Tensor]]) -> tuple[torch.Tensor, torch.Tensor]:
    """``r = |sum_i l_i p_i|`` and ``r - sum_i l_i`` without cancellation: with ``s = sum_i l_i``,
    ``r^2 - s^2 = -sum_{i<j} l_i l_j |p_i - p_j|^2``, so ``r - s = -sum_{i<j} l_i l_j |p_i - p_j|^2 / (r + s)``
    (exact in float32 for nearly aligned sharp lobes, where ``r - s`` is tiny against ``s``)."""
    r = sum(lam.unsqueeze(-1) * p for p, lam in lobes).norm(dim=-1)  # type: ignore[union-attr]
    s = sum(lam for _, lam in lobes)
    cross = 0
    for i in range(len(lobes)):
        for j in range(i + 1, len(lobes)):
            (pi, li), (pj, lj) = lobes[i], lobes[j]
            cross = cross + li * lj * ((pi - pj) ** 2).sum(-1)
    return r, -cross / (r + s).clamp(min=torch.finfo(r.dtype).tiny)  # type: ignore[operator]


def sg_eval(axis: torch.Tensor, sharpness: torch.Tensor, amplitude: torch.Tensor,
            dirs: torch.Tensor) -> torch.Tensor:
    """Sum of ``K`` SGs at ``N`` directions.

    Args:
        axis: ``(K, 3)`` unit axes. sharpness: ``(K,)``. amplitude: ``(K,)`` or ``(K, C)``.
        dirs: ``(N, 3)`` unit directions.

    Returns:
        ``(N, C)`` (or ``(N,)`` for scalar amplitudes): ``sum_k mu_k exp(lambda_k (d . p_k - 1))``.
    """
    axis, dirs = _tensor(axis, "axis"), _tensor(dirs, "directions")
    sharpness, amplitude = _tensor(sharpness, "sharpness", axis), _tensor(amplitude, "amplitude", axis)
    dims = check_shape(axis, "K 3", name="sg_eval axis")
    check_shape(sharpness, "K", name="sg_eval sharpness", dims=dims)
    check_shape(dirs, "N 3", name="sg_eval directions")
    _check_lobe(axis, sharpness, amplitude)
    check(bool(torch.isfinite(dirs).all()), "sg_eval directions contain NaN or Inf")
    dirs = dirs.to(axis.dtype)
    w = torch.exp(sharpness[None, :] * (dirs @ axis.T - 1))  # (N, K)
    return w @ amplitude


def sg_product(p1: torch.Tensor, l1: torch.Tensor, m1: torch.Tensor,
               p2: torch.Tensor, l2: torch.Tensor, m2: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """The product of two SGs is an SG: ``G1 G2 = SG(p, lambda, mu)`` (broadcasting; see module docstring).

    ``lambda = |l1 p1 + l2 p2|`` (may reach 0 for opposite axes of equal sharpness: the product is then the
    constant ``mu`` and the axis is ``p1``), ``p = (l1 p1 + l2 p2) / lambda``, ``mu = m1 m2 exp(lambda - l1 - l2)``.

    Returns:
        ``(p (..., 3), lambda (...), mu (...) or (..., C))``.
    """
    p1, p2 = _tensor(p1, "axis"), _tensor(p2, "axis")
    l1, m1, l2, m2 = (_tensor(t, n, p1) for t, n in ((l1, "sharpness"), (m1, "amplitude"),
                                                     (l2, "sharpness"), (m2, "amplitude")))
    _check_lobe(p1, l1, m1, " 1")
    _check_lobe(p2, l2, m2, " 2")
    v = l1.unsqueeze(-1) * p1 + l2.unsqueeze(-1) * p2
    lam, deficit = _norm_and_deficit([(p1, l1), (p2, l2)])
    zero = lam <= 1e-12 * (l1 + l2)
    p = torch.where(zero.unsqueeze(-1), torch.broadcast_to(p1, v.shape),
                    v / torch.where(zero, torch.ones_like(lam), lam).unsqueeze(-1))
    scale = torch.exp(deficit)
    if m1.ndim == l1.ndim and m2.ndim == l2.ndim:
        mu = m1 * m2 * scale
    else:
        mu = _chan(m1, l1) * _chan(m2, l2) * scale.unsqueeze(-1)
    return p, lam, mu


def sg_integral(sharpness: torch.Tensor, amplitude: torch.Tensor) -> torch.Tensor:
    """Integral of each SG over the sphere: ``2 pi mu / lambda (1 - exp(-2 lambda))``.

    Args:
        sharpness: ``(...)`` > 0. amplitude: ``(...)`` or ``(..., C)``.

    Returns:
        the amplitude's shape (broadcast with the sharpness).
    """
    lam = _tensor(sharpness, "sharpness")
    mu = _tensor(amplitude, "amplitude", lam)
    check(mu.ndim in (lam.ndim, lam.ndim + 1), f"SG amplitude must have the sharpness shape {tuple(lam.shape)} or "
          f"that plus a channel axis, got {tuple(mu.shape)}")
    if not bool(torch.isfinite(lam).all()) or not bool(torch.isfinite(mu).all()):
        raise PrtError("SG sharpness or amplitude contains NaN or Inf")
    if lam.numel() and not bool((lam > 0).all()):
        raise PrtError(f"SG sharpness (lambda) must be > 0, got min {float(lam.min()):.6g}")
    k = _sinhc_scaled(lam, torch.zeros_like(lam))  # r = lambda for a single lobe
    return mu * (k.unsqueeze(-1) if mu.ndim == lam.ndim + 1 else k)


def _kernel(lobes: list[tuple[torch.Tensor, torch.Tensor, torch.Tensor]]) -> torch.Tensor:
    """``int prod_i G_i / prod_i mu_i`` over the sphere for 2 or 3 lobes, broadcast batch shape."""
    r, deficit = _norm_and_deficit([(p, lam) for p, lam, _ in lobes])
    return _sinhc_scaled(r, deficit)


def _times_amplitudes(k: torch.Tensor, lobes: list[tuple[torch.Tensor, torch.Tensor, torch.Tensor]]) -> torch.Tensor:
    if all(mu.ndim == lam.ndim for _, lam, mu in lobes):
        out = k
        for _, _, mu in lobes:
            out = out * mu
        return out
    out = k.unsqueeze(-1)
    for _, lam, mu in lobes:
        out = out * _chan(mu, lam)
    return out


def sg_inner(p1: torch.Tensor, l1: torch.Tensor, m1: torch.Tensor,
             p2: torch.Tensor, l2: torch.Tensor, m2: torch.Tensor) -> torch.Tensor:
    """``int_S2 G1(v) G2(v) dv = 4 pi m1 m2 sinh(r) / (r exp(l1 + l2))``, ``r = |l1 p1 + l2 p2|`` (broadcasting).

    Returns:
        the broadcast batch shape (plus the channel axis where an amplitude has one).
    """
    p1, p2 = _tensor(p1, "axis"), _tensor(p2, "axis")
    lobes = []
    for i, (p, l, m) in enumerate(((p1, l1, m1), (p2, l2, m2))):
        lam, mu = _tensor(l, "sharpness", p), _tensor(m, "amplitude", p)
        _check_lobe(p, lam, mu, f" {i + 1}")
        lobes.append((p, lam, mu))
    return _times_amplitudes(_kernel(lobes), lobes)


def sg_triple(light: SGLike, brdf: SGLike, vis: SGLike) -> torch.Tensor:
    """Analytic triple-product integral (seed 004, eq. 4), broadcasting, NOT summed.

    ``int_S2 L(v) rho(v) V(v) dv = 4 pi mu_L mu_rho mu_V sinh(r) / (r exp(l_L + l_rho + l_V))`` with
    ``r = |l_L p_L + l_rho p_rho + l_V p_V|``.

    Args:
        light, brdf, vis: each an :class:`~prt_torch.sg.lobes.SGLobes` or an ``(axis (..., 3), sharpness (...),
            amplitude (...) or (..., C))`` tuple; batch shapes broadcast, e.g. light ``(1, L, 1, 1)``, brdf
            ``(V, 1, B, 1)``, visibility ``(V, 1, 1, S)`` -> ``(V, L, B, S[, C])``; sum the axes you need.

    Returns:
        the broadcast batch shape, plus a trailing channel axis where any amplitude has one.
    """
    lobes = [_unpack(sg, f" {name}") for sg, name in ((light, "light"), (brdf, "brdf"), (vis, "visibility"))]
    for (p, lam, mu), name in zip(lobes, ("light", "brdf", "visibility"), strict=True):
        _check_lobe(p, lam, mu, f" {name}")
    dt = torch.promote_types(torch.promote_types(lobes[0][0].dtype, lobes[1][0].dtype), lobes[2][0].dtype)
    lobes = [(p.to(dt), lam.to(dt), mu.to(dt)) for p, lam, mu in lobes]
    return _times_amplitudes(_kernel(lobes), lobes)


def cone_half_angle(sharpness: torch.Tensor) -> torch.Tensor:
    """Seed 004 eq. 5-6: the half-angle ``alpha`` where the SG falls to 0.5: ``acos(log(0.5)/lambda + 1)``
    (``pi`` for ``lambda <= log 2 / 2``: the half-maximum is never reached on the sphere)."""
    lam = _tensor(sharpness, "sharpness")
    return torch.acos(torch.clamp(math.log(0.5) / lam + 1.0, -1.0, 1.0))


def sharpness_for_half_angle(alpha: torch.Tensor | float) -> torch.Tensor:
    """Inverse of :func:`cone_half_angle`: ``lambda = log 2 / (1 - cos alpha)``."""
    a = _tensor(alpha, "half angle")
    return math.log(2.0) / (1 - torch.cos(a))

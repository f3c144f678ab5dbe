"""Per-vertex SG shading with cone visibility (seed 004 eq. 2-4): ``sum_k sum_j`` light SG x BRDF SG x visibility.

**The light** (:class:`SGLight`, :func:`sg_light_from_env`): the environment is split, pixel by pixel, into its
detected peaks (seed 004 Fig. 6) and the rest. Around each peak found by
:func:`prt_torch.sg.lighting.detect_peaks` (pixels within ``3`` cap radii + 2 detection pixels of its direction),
every pixel above the detection threshold and brighter than 1.5 x the background (the median of a ring just
outside) is set to the background;
what was removed is the peak's power ``P_p`` (RGB), carried by the peak's 1-3 moment-fitted SGs rescaled so
their integral is ``P_p``.
The clamped map (smooth) is fitted by the multiscale HEALPix residual scheme
(:func:`prt_torch.sg.lighting.fit_envmap_sg`, ``peaks=False``). So ``rest + peaks`` is the map itself and no
light is counted twice.

**The shading** (:func:`shade_sg`): with BRDF lobes ``rho_j`` per vertex (:meth:`~prt_torch.sg.brdf_fit.SGBRDF.
view_lobes`), light lobes ``L_k`` and, for each BRDF lobe, cones ``c`` with traced visibility ``V_c`` and cone
SGs ``G_c`` (axis the cone's, sharpness from its half-angle by eq. 5-6), the outgoing radiance is::

    B = sum_j sum_k  T2(L_k, rho_j) * Veff_jk,      T2 = int L_k rho_j  (sg_inner)
    Veff_jk = sum_c V_c T3(L_k, rho_j, G_c) / sum_c T3(L_k, rho_j, G_c)      (eq. 4 per cone, normalised)

for the rest lobes: the visibility of light lobe ``k`` seen through BRDF lobe ``j`` is the average of that lobe's
cone visibilities weighted by how much each cone's SG overlaps the product ``L_k rho_j`` (exactly ``T2`` when
nothing is occluded; light from one side sees the cones on that side). A peak lobe uses the visibility of its
peak's own cone (``V_peak``: seed 004 Fig. 8, "extra importance sampling" of the hemisphere) when peak cones are
given, else the same sub-cone average as the rest (the Fig. 8 ablation). Torch, batched over vertices in chunks;
no loop over vertices, lobes or cones.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch

from prt_torch.errors import PrtError, check
from prt_torch.sg.lobes import SGLobes
from prt_torch.shapes import check_shape

LOG_HALF = math.log(0.5)


@dataclass
class SGLight:
    """Lighting for :func:`shade_sg` (world frame, z up).

    Attributes:
        lobes: the rest of the environment (peaks removed), RGB radiance SGs ``(K,)``.
        peak_lobes: every peak's SGs, concatenated ``(Kp,)`` (their integrals are the peaks' powers).
        peak_index: ``(Kp,)`` long: the peak each peak lobe belongs to.
        peak_dirs: ``(P, 3)`` unit directions; peak_solid_angle: ``(P,)`` steradians (cap at half maximum).
        rel_error: the rest fit's relative L2 residual per scale; source: a description.
    """

    lobes: SGLobes
    peak_lobes: SGLobes
    peak_index: torch.Tensor
    peak_dirs: torch.Tensor
    peak_solid_angle: torch.Tensor
    rel_error: list[float]
    source: str = ""

    @property
    def n_peaks(self) -> int:
        return int(self.peak_dirs.shape[0])

    def to(self, device: torch.device | str, dtype: torch.dtype = torch.float32) -> SGLight:
        return SGLight(self.lobes.to(dtype, device), self.peak_lobes.to(dtype, device), self.peak_index.to(device),
                       self.peak_dirs.to(device, dtype), self.peak_solid_angle.to(device, dtype), self.rel_error,
                       self.source)

    def all_lobes(self) -> SGLobes:
        """Rest + peak lobes (the whole environment)."""
        return _cat([self.lobes, self.peak_lobes])


def _cat(parts: list[SGLobes]) -> SGLobes:
    """Concatenate lobe sets (dtype and device of the first)."""
    d, dev = parts[0].dtype, parts[0].device
    return SGLobes(*(torch.cat([getattr(p, k).to(device=dev, dtype=d) for p in parts])
                     for k in ("axis", "sharpness", "amplitude")))


def add_sun_disk(env: Any, direction: np.ndarray, half_angle: float, power: np.ndarray, source: str = "") -> Any:
    """``env`` (an :class:`~prt_torch.light.envmap.EnvMap`) plus a uniform sun disk: the pixels whose centre lies
    within ``half_angle`` of the unit ``direction`` share the RGB ``power`` (``int L dOmega``) equally per
    steradian, so the map carries exactly that power. A disk smaller than one pixel is an error."""
    from prt_torch.light.envmap import EnvMap

    d = np.asarray(direction, dtype=np.float64)
    d = d / np.linalg.norm(d)
    img = env.image.astype(np.float64)
    inside = env.directions() @ d >= math.cos(half_angle)
    check(bool(inside.any()), "the sun disk is smaller than a pixel of the environment map: raise its size")
    img[inside] += np.asarray(power, dtype=np.float64) / float(env.solid_angles()[inside].sum())
    return EnvMap(img.astype(np.float32), env.layout, source=source or env.source)


def sun_map_height(half_angle: float, lo: int = 512, hi: int = 2048) -> int:
    """Rows of a lat-long map whose pixels resolve a sun of ``half_angle`` radians (>= 3 pixels in radius)."""
    need = 3 * math.pi / max(half_angle, 1e-9)
    return int(min(hi, max(lo, 2 ** math.ceil(math.log2(max(need, 1.0))))))


def _luminance(rgb: np.ndarray) -> np.ndarray:
    from prt_torch.sg.lighting import LUMA

    return rgb @ LUMA


def split_peaks(env: Any, peaks: list[Any], ratio: float = 1.5, sigma: float = 4.0,
                fraction: float = 0.05) -> tuple[Any, list[np.ndarray]]:
    """``(rest EnvMap, [P_p (3,) RGB power removed per peak])``: around each peak, the pixels above the detection
    threshold (``max(mean + sigma std, fraction max)`` of the luminance, solid-angle weighted, as
    :func:`~prt_torch.sg.lighting.detect_peaks`) and brighter than ``ratio`` times the background (the median of a
    ring around the peak) are set to the background; what was removed is the peak's power (module docstring).
    ``peaks``: :class:`~prt_torch.sg.lighting.Peak` list."""
    from prt_torch.light.envmap import EnvMap

    check(isinstance(env, EnvMap), f"expected an EnvMap, got {type(env).__name__}")
    img = env.image.astype(np.float64)
    omega = env.solid_angles()
    dirs = env.directions()
    lum = _luminance(img)
    wsum = float(omega.sum())
    mean = float((lum * omega).sum() / wsum)
    thr = max(mean + sigma * math.sqrt(float((((lum - mean) ** 2) * omega).sum() / wsum)), fraction * float(lum.max()))
    rest = img.copy()
    powers = []
    taken = np.zeros(lum.shape, dtype=bool)
    for p in peaks:  # a handful of peaks, each vectorised over pixels
        d = np.asarray(p.direction, dtype=np.float64)
        cap = math.acos(max(-1.0, 1.0 - p.solid_angle / (2 * math.pi)))
        pix = math.sqrt(p.solid_angle / max(p.n_pixels, 1))  # detection pixel size (radians)
        radius = min(math.pi / 2, 3.0 * cap + 2.0 * pix)
        cosd = dirs @ d
        near = cosd >= math.cos(radius)
        ring = (cosd < math.cos(radius)) & (cosd >= math.cos(min(math.pi, 1.5 * radius + pix)))
        bg = np.median(img[ring], axis=0) if ring.any() else np.zeros(3)
        hot = near & (lum > max(thr, ratio * float(_luminance(bg)))) & ~taken
        taken |= hot
        removed = np.where(hot[..., None], np.maximum(img - bg, 0.0), 0.0)
        rest = rest - removed
        powers.append((removed * omega[..., None]).reshape(-1, 3).sum(0))
    return EnvMap(rest.astype(np.float32), env.layout, source=f"{env.source} (peaks clamped)"), powers


def sg_light_from_env(env: Any, peaks: bool = True, max_level: int = 2, rel_threshold: float = 0.02,
                      max_peaks: int = 4, dtype: torch.dtype = torch.float32, **peak_kwargs: float) -> SGLight:
    """:class:`SGLight` of an :class:`~prt_torch.light.envmap.EnvMap`: peaks detected and split off (module
    docstring), the rest fitted up to HEALPix scale ``max_level``; ``peaks=False``: no split, no peaks."""
    from prt_torch.sg.lighting import detect_peaks, fit_envmap_sg

    found = detect_peaks(env, max_peaks=max_peaks, dtype=torch.float64, **peak_kwargs) if peaks else []
    rest, powers = split_peaks(env, found)
    fit = fit_envmap_sg(rest, max_level=max_level, rel_threshold=rel_threshold, peaks=False, dtype=dtype)
    plobes, pidx = [], []
    for i, (p, pw) in enumerate(zip(found, powers, strict=True)):
        if not np.all(np.isfinite(pw)) or float(pw.max()) <= 0:
            continue
        lo = p.lobes.to(torch.float64)
        total = lo.integral().numpy()
        ratio = np.where(total > 0, pw / np.maximum(total, 1e-30), 0.0)
        plobes.append(SGLobes(lo.axis, lo.sharpness, lo.amplitude * torch.as_tensor(ratio)))
        pidx.append(torch.full((len(lo),), i, dtype=torch.long))
    keep = [i for i, pw in enumerate(powers) if np.all(np.isfinite(pw)) and float(pw.max()) > 0]
    pl = _cat(plobes).to(dtype) if plobes else SGLobes.empty(dtype)
    # peak indices renumbered to the kept peaks
    remap = {old: new for new, old in enumerate(keep)}
    index = torch.cat(pidx) if pidx else torch.zeros(0, dtype=torch.long)
    index = torch.as_tensor([remap[int(i)] for i in index.tolist()], dtype=torch.long)
    pd = torch.as_tensor(np.array([found[i].direction for i in keep]).reshape(-1, 3), dtype=dtype)
    ps = torch.as_tensor(np.array([found[i].solid_angle for i in keep], dtype=np.float64), dtype=dtype)
    src = f"{env.source}: {len(fit.lobes)} SGs (HEALPix scales 0..{len(fit.rel_error_per_scale) - 1}, rel. error " \
          f"{fit.rel_error_per_scale[-1]:.3f}) + {len(keep)} peaks ({len(pl)} SGs)"
    return SGLight(fit.lobes, pl, index, pd, ps, fit.rel_error_per_scale, src)


def _pair_kernel(u: torch.Tensor, su: torch.Tensor, lp: torch.Tensor, ll: torch.Tensor) -> torch.Tensor:
    """``int G_u G_k`` kernels for every ``u`` and light lobe ``k`` (unit amplitudes), where ``u = sum_i l_i p_i``
    ``(..., 3)`` is the already-combined sharpness-weighted axes of the other lobes and ``su`` ``(...)`` their
    sharpness sum: ``r = |u + l_k p_k|`` by one GEMM, ``r^2 = |u|^2 + l_k^2 + 2 l_k (u . p_k)`` -> ``(..., K)``."""
    r = (u @ (2.0 * ll[:, None] * lp).T).add_((u * u).sum(-1, keepdim=True)).add_(ll * ll)  # r^2, (..., K)
    r = r.clamp_(min=1e-12).sqrt_()
    # 4 pi sinh(r) / (r e^s) = 2 pi e^(r - s) (1 - e^(-2r)) / r, overflow-free (r <= s)
    e = torch.exp(r - (su[..., None] + ll))
    return e.mul_(torch.expm1(-2.0 * r).neg_()).div_(r.clamp_(min=1e-6)).mul_(2.0 * math.pi)


def shade_sg(light: SGLight, brdf_axis: torch.Tensor, brdf_sharpness: torch.Tensor, brdf_amplitude: torch.Tensor,
             cone_axis: torch.Tensor, cone_half_angle: torch.Tensor, cone_vis: torch.Tensor,
             peak_vis: torch.Tensor | None = None, chunk: int | None = None) -> torch.Tensor:
    """Outgoing radiance ``(V, 3)`` per vertex (module docstring).

    Args:
        light: :class:`SGLight` (same device as the tensors).
        brdf_axis ``(V, J, 3)``, brdf_sharpness ``(V, J)``, brdf_amplitude ``(V, J, 3)``: BRDF x cosine lobes.
        cone_axis ``(V, J, C, 3)``, cone_half_angle ``(V, J, C)``, cone_vis ``(V, J, C)``: each BRDF lobe's cones
            and their traced visibility (``C`` = 7 or 1).
        peak_vis: ``(V, P)`` visibility of the peak cones, or ``None`` (peak lobes use the sub-cones: ablation).
        chunk: vertices per block (default: ~4M kernel terms per block).
    """
    v, j = brdf_sharpness.shape
    c = cone_vis.shape[-1]
    check_shape(brdf_axis, (v, j, 3), name="shade_sg: BRDF lobe axes")
    check_shape(brdf_amplitude, (v, j, 3), name="shade_sg: BRDF lobe amplitudes")
    check_shape(cone_axis, (v, j, c, 3), name="shade_sg: cone axes")
    check_shape(cone_half_angle, (v, j, c), name="shade_sg: cone half-angles")
    if peak_vis is not None:
        check_shape(peak_vis, (v, light.n_peaks), name="shade_sg: peak visibility")
    for name, t in (("BRDF sharpness", brdf_sharpness), ("cone visibility", cone_vis)):
        if not bool(torch.isfinite(t).all()):
            raise PrtError(f"shade_sg: {name} contains NaN or Inf")
    if bool((brdf_sharpness <= 0).any()):
        raise PrtError("shade_sg: BRDF sharpness (lambda) must be > 0")
    lam_c = LOG_HALF / (torch.cos(cone_half_angle.clamp(1e-3, math.pi)) - 1.0)  # eq. 5-6 inverse
    out = torch.zeros(v, 3, dtype=brdf_amplitude.dtype, device=brdf_amplitude.device)
    parts = [(light.lobes, None)]
    if len(light.peak_lobes):
        parts.append((light.peak_lobes, light.peak_index))
    if chunk is None:
        chunk = max(1, int(4e6 // max(1, j * max(len(light.lobes), 1) * c)))
    for v0 in range(0, v, chunk):
        sl = slice(v0, min(v, v0 + chunk))
        pa, la, ma = brdf_axis[sl], brdf_sharpness[sl], brdf_amplitude[sl]  # (n, J, ...)
        ua = la[..., None] * pa  # (n, J, 3)
        uc = ua[:, :, None] + lam_c[sl][..., None] * cone_axis[sl]  # (n, J, C, 3): BRDF lobe + cone
        sc = la[:, :, None] + lam_c[sl]
        cv = cone_vis[sl]
        for lobes, pidx in parts:  # rest lobes, then peak lobes
            if len(lobes) == 0:
                continue
            lp, ll, lm = lobes.axis, lobes.sharpness, lobes.amplitude  # (K, ...)
            # T2 (n, J, K) x amplitudes: int L_k rho_j
            t2 = _pair_kernel(ua, la, lp, ll)
            if pidx is not None and peak_vis is not None:
                veff = peak_vis[sl][:, None, :].expand(-1, j, -1)[:, :, pidx]  # (n, J, Kp)
            else:
                k3 = _pair_kernel(uc, sc, lp, ll)  # (n, J, C, K): int L_k rho_j G_c
                den = k3.sum(2)
                veff = torch.where(den > 1e-30, (k3 * cv[..., None]).sum(2) / den.clamp(min=1e-30),
                                   cv.mean(-1)[..., None])  # no overlap at all (underflow): the plain mean
            # sum_j sum_k T2 veff mu_rho mu_L
            out[sl] += torch.einsum("njk,njc,kc->nc", t2 * veff, ma, lm)
    return out

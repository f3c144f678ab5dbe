"""The ``reference``: the rendering integral per vertex by Monte-Carlo with Embree rays, no SH anywhere.

``L(wo) = int_{H(n)} L_env(wi) V(wi) f(wi, wo) cos(theta_i) dwi + sum_disk int_disk L_d V(wi) f(wi, wo) cos dwi``

* ``L_env``: the full-resolution radiance function of the lighting, as its light split (:func:`split_reference`,
  :func:`compare_lights`): the residual - for the player's procedural sky the CIE clear sky + ground of
  :func:`prt_torch.light.sources.sky_envmap` evaluated directly at each ray direction (:func:`sky_radiance`, with the
  colours the player's :func:`~prt_torch.light.sources.sky_sh` call uses), for an HDR file the nearest pixel of the
  residual map (no SH projection, no window) - plus every peak light (the sky's sun, a map's detected suns, ``--light
  sun``'s disk) as a uniform DISK light of the peak's own angular radius and radiance, sampled with its own rays
  (``sum_disk`` above). Hemisphere rays alone would find a map's 6.8e-5 sr sun by chance.
* ``f``: the analytic BRDF (:func:`prt_torch.brdf.rpo.builtin_brdf`, tint included), no factorisation.
* ``V``: Embree occlusion from ``p + offset n`` (the bake's ray offset) against the posed mesh.
* Sampling: a randomised spherical-Fibonacci hemisphere set of ``R`` directions about each vertex normal
  (:func:`prt_torch.sh.quadrature.hemisphere_directions` with a seed, each turned about the normal by a
  per-vertex angle: the bake's :class:`~prt_torch.bake.trace.RaySet` machinery), weight ``2 pi / R``.
  Vectorised over blocks of vertices (no loop over vertices or rays).

Two independent estimates (different seeds) are averaged; their disagreement measures the Monte-Carlo
noise (:func:`reference_pair`).
"""

from __future__ import annotations

import inspect
import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from prt_torch.errors import PrtError, check
from prt_torch.shapes import check_shape


@dataclass
class ReferenceLight:
    """A radiance function ``radiance(dirs (N, 3) world) -> (N, 3)`` plus delta lights ``[(direction (3,),
    power (3,))]`` (irradiance on a surface facing the light), uniform disk lights ``[(direction (3,), half_angle,
    radiance (3,))]`` (sampled with their own rays: :func:`reference_radiance` ``disk_rays``), and a description."""

    radiance: Callable[[np.ndarray], np.ndarray]
    deltas: list[tuple[np.ndarray, np.ndarray]] = field(default_factory=list)
    source: str = ""
    disks: list[tuple[np.ndarray, float, np.ndarray]] = field(default_factory=list)


def sky_radiance() -> Callable[[np.ndarray], np.ndarray]:
    """The player's procedural sky WITHOUT its sun as a radiance function ``(N, 3) -> (N, 3)`` (the image of
    :func:`~prt_torch.light.sources.sky_envmap`, the CIE clear sky + ground of ``load_lighting(None, order)``,
    evaluated at any direction: full resolution)."""
    from prt_torch.light.sources import cie_clear_sky, sky_sh
    from prt_torch.player.lighting import DEFAULT_SUN_DIRECTION

    defaults = {k: p.default for k, p in inspect.signature(sky_sh).parameters.items()}
    sky = np.asarray(defaults["sky_color"], dtype=np.float64)
    ground = np.asarray(defaults["ground_color"], dtype=np.float64)
    sun = np.asarray(DEFAULT_SUN_DIRECTION, dtype=np.float64)
    sun = sun / np.linalg.norm(sun)

    def radiance(dirs: np.ndarray) -> np.ndarray:
        d = np.asarray(dirs, dtype=np.float64)
        return cie_clear_sky(d, sun)[..., None] * sky + (d[..., 2] <= 0)[..., None] * ground

    return radiance


def envmap_radiance(env: Any) -> Callable[[np.ndarray], np.ndarray]:
    """An :class:`~prt_torch.light.envmap.EnvMap` as a nearest-pixel radiance function ``(N, 3) -> (N, 3)`` (full
    resolution, no SH projection, no window)."""
    from prt_torch.light.envmap import latlong_pixel_coords, probe_pixel_coords

    img = env.image.astype(np.float64)
    h, w = env.shape
    coords = latlong_pixel_coords if env.layout == "latlong" else probe_pixel_coords

    def radiance(dirs: np.ndarray) -> np.ndarray:
        uv = coords(np.asarray(dirs, dtype=np.float64))
        col = np.clip((uv[..., 0] * w).astype(np.int64), 0, w - 1)
        row = np.clip((uv[..., 1] * h).astype(np.int64), 0, h - 1)
        return img[row, col]

    return radiance


def envmap_reference(path: str | Path) -> ReferenceLight:
    """An HDR environment map as a nearest-pixel radiance function (full resolution)."""
    from prt_torch.light.envmap import load_envmap

    env = load_envmap(path)
    h, w = env.shape
    return ReferenceLight(envmap_radiance(env), [], f"{path} (nearest pixel, {w}x{h})")


def split_reference(split: Any, env: str | Path | None) -> ReferenceLight:
    """The lighting of ``prt compare --light sky`` at full resolution as its light split (:class:`~prt_torch.sg.
    split.LightSplit` of ``env``, :func:`prt_torch.player.peaks.load_split`): the residual's radiance function (the
    procedural sky: :func:`sky_radiance`, the CIE sky + ground without the sun; a map: the residual map's nearest
    pixel, :func:`envmap_radiance`) plus every peak as a uniform disk light of the SAME angular radius and radiance
    (sampled with its own rays, :func:`reference_radiance` ``disk_rays``) instead of a delta or a few map pixels
    that hemisphere rays would hit by chance. Peaks + residual are the map (the split conserves energy)."""
    from prt_torch.player.peaks import is_sky

    base = sky_radiance() if is_sky(env) else envmap_radiance(split.residual)
    disks = [(p.direction, float(p.angular_radius), p.radiance) for p in split.peaks]
    what = "procedural sky (CIE clear sky + ground)" if is_sky(env) else \
        f"{env} residual (nearest pixel, {split.residual.shape[1]}x{split.residual.shape[0]})"
    sizes = ", ".join(f"{math.degrees(p.angular_radius):.3g}" for p in split.peaks)
    return ReferenceLight(base, [], f"{what} + {len(disks)} peak disk(s) (half-angle {sizes or '-'} deg)", disks)


def reference_radiance(positions: np.ndarray, frames: np.ndarray, faces: np.ndarray, eye: np.ndarray,
                       light: ReferenceLight, brdfs: Mapping[str, Any], n_rays: int, seed: int, offset: float,
                       max_rays: int = 1 << 19, disk_rays: int = 64, scene: Any = None) -> dict[str, np.ndarray]:
    """One Monte-Carlo estimate of the outgoing radiance toward ``eye`` of every vertex of one posed frame.

    Args:
        positions: ``(V, 3)`` world; frames: ``(V, 3, 3)`` rows ``(t, b, n)``; faces: ``(T, 3)``.
        eye: ``(3,)`` camera position.
        light: :class:`ReferenceLight`.
        brdfs: ``{name: BRDF}`` analytic BRDFs (:mod:`prt_torch.brdf.analytic`; ``brdf(wi, wo) -> (N, 3)``).
        n_rays: hemisphere directions per vertex ``R``; seed: the estimate's seed.
        offset: ray origin offset along the normal (world units).
        max_rays: rays per block (memory bound).
        disk_rays: rays per vertex and disk light (uniform in the disk's cap, randomised per seed).
        scene: trace against this :class:`~prt_torch.bake.embree.RayScene` (e.g. the characters above a floor whose
            vertices are the receivers) instead of the mesh ``(positions, faces)``.

    Returns:
        ``{name: (V, 3) float64}``; the radiance of a vertex seen from below its horizon (``wo.z <= 0``) is 0
        (the analytic BRDFs vanish there), see :func:`front_facing`.
    """
    from prt_torch.bake.directions import rotated_frames, vertex_angles, world_directions
    from prt_torch.bake.embree import RayScene
    from prt_torch.sh.quadrature import hemisphere_directions

    positions = np.asarray(positions, dtype=np.float64)
    frames = np.asarray(frames, dtype=np.float64)
    v = positions.shape[0]
    check_shape(frames, (v, 3, 3), name="reference: frames")
    check(n_rays >= 1, f"reference: need >= 1 ray per vertex, got {n_rays}")
    if not (np.isfinite(positions).all() and np.isfinite(frames).all()):
        raise PrtError("reference: positions or frames contain NaN or Inf")
    if scene is None:
        scene = RayScene(positions.astype(np.float32), np.asarray(faces))
    local = hemisphere_directions(int(n_rays), seed=int(seed))  # (R, 3)
    phi = vertex_angles(v, int(seed) + 7919)
    view = np.asarray(eye, dtype=np.float64) - positions
    view /= np.maximum(np.linalg.norm(view, axis=-1, keepdims=True), 1e-12)
    wo_all = np.einsum("vij,vj->vi", frames, view)
    wo_all /= np.linalg.norm(wo_all, axis=-1, keepdims=True)
    origins_all = positions + offset * frames[:, 2]
    out = {name: np.zeros((v, 3)) for name in brdfs}
    weight = 2 * math.pi / n_rays
    vb = max(1, max_rays // n_rays)
    for v0 in range(0, v, vb):
        v1 = min(v, v0 + vb)
        n = v1 - v0
        f = frames[v0:v1]
        world = world_directions(local, rotated_frames(f, phi[v0:v1]))  # (R, n, 3)
        world /= np.linalg.norm(world, axis=-1, keepdims=True)
        wi = np.einsum("vij,rvj->rvi", f, world)  # local directions (R, n, 3)
        wi /= np.linalg.norm(wi, axis=-1, keepdims=True)
        origins = np.broadcast_to(origins_all[v0:v1], (n_rays, n, 3))
        occ = scene.occluded(np.ascontiguousarray(origins, dtype=np.float32).reshape(-1, 3),
                             np.ascontiguousarray(world, dtype=np.float32).reshape(-1, 3))
        vis = np.logical_not(occ).reshape(n_rays, n)
        le = light.radiance(world.reshape(-1, 3)).reshape(n_rays, n, 3)
        cos = np.maximum(wi[..., 2], 0.0)
        wo = np.broadcast_to(wo_all[v0:v1], (n_rays, n, 3)).reshape(-1, 3)
        for name, brdf in brdfs.items():
            fr = brdf(wi.reshape(-1, 3), np.ascontiguousarray(wo)).reshape(n_rays, n, 3)
            out[name][v0:v1] += weight * np.einsum("rvc,rv->vc", le * fr, vis * cos)
        for d, power in light.deltas:
            s_world = np.broadcast_to(d, (n, 3))
            s_local = np.einsum("vij,j->vi", f, d)
            s_local /= np.linalg.norm(s_local, axis=-1, keepdims=True)
            lit = np.logical_not(scene.occluded(origins_all[v0:v1].astype(np.float32),
                                                np.ascontiguousarray(s_world, dtype=np.float32)))
            cs = np.maximum(s_local[:, 2], 0.0) * lit
            for name, brdf in brdfs.items():
                out[name][v0:v1] += power * brdf(s_local, wo_all[v0:v1]) * cs[:, None]
        for d, half, rad in light.disks:
            _add_disk(out, scene, f, origins_all[v0:v1], wo_all[v0:v1], slice(v0, v1), np.asarray(d, np.float64),
                      float(half), np.asarray(rad, np.float64), brdfs, int(disk_rays), int(seed))
    return out


def _add_disk(out: dict[str, np.ndarray], scene: Any, frames: np.ndarray, origins: np.ndarray, wo: np.ndarray,
              sl: slice, d: np.ndarray, half: float, rad: np.ndarray, brdfs: Mapping[str, Any], n: int,
              seed: int) -> None:
    """Add a uniform disk light (cap of half-angle ``half`` about ``d``, radiance ``rad``) to ``out[name][sl]``:
    ``n`` stratified directions uniform in the cap (a randomised spherical-Fibonacci cap set, turned per seed),
    Embree visibility, analytic BRDF, weight ``Omega / n``."""
    from prt_torch.sh.quadrature import hemisphere_directions

    check(n >= 1, f"reference: need >= 1 ray per disk light, got {n}")
    loc = hemisphere_directions(n, seed=seed + 31)  # z uniform in [0, 1] -> rescale into the cap
    c = math.cos(half)
    z = 1.0 - loc[:, 2] * (1.0 - c)
    r = np.sqrt(np.maximum(0.0, 1.0 - z * z))
    phi = np.arctan2(loc[:, 1], loc[:, 0])
    t1 = np.cross(d, [0.0, 0.0, 1.0] if abs(d[2]) < 0.9 else [1.0, 0.0, 0.0])
    t1 /= np.linalg.norm(t1)
    t2 = np.cross(d, t1)
    dirs = (r * np.cos(phi))[:, None] * t1 + (r * np.sin(phi))[:, None] * t2 + z[:, None] * d  # (n, 3) world
    nv = origins.shape[0]
    world = np.broadcast_to(dirs[:, None, :], (n, nv, 3))
    occ = scene.occluded(np.ascontiguousarray(np.broadcast_to(origins, (n, nv, 3)), dtype=np.float32).reshape(-1, 3),
                         np.ascontiguousarray(world, dtype=np.float32).reshape(-1, 3)).reshape(n, nv)
    wi = np.einsum("vij,rj->rvi", frames, dirs)  # (n, V, 3) local
    wi /= np.linalg.norm(wi, axis=-1, keepdims=True)
    cos = np.maximum(wi[..., 2], 0.0) * np.logical_not(occ)
    w = 2 * math.pi * (1.0 - c) / n
    wo_b = np.ascontiguousarray(np.broadcast_to(wo, (n, nv, 3))).reshape(-1, 3)
    for name, brdf in brdfs.items():
        fr = brdf(wi.reshape(-1, 3), wo_b).reshape(n, nv, 3)
        out[name][sl] += w * np.einsum("rvc,rv->vc", fr, cos) * rad


# -- the lightings of ``prt compare --light`` ------------------------------------------------------------------------

#: ``--light`` choices: the player's sky (CIE sky + ground + its sun as a delta light / SH disk), the same sky
#: without the sun (smooth), or the sky (or ``--env`` map) plus a small bright sun disk (sharp)
LIGHTS = ("sky", "smooth", "sun")
#: default sun of ``--light sun``: half-angle (degrees) and power (RGB irradiance on a facing surface)
SUN_HALF_ANGLE_DEG = 2.0
SUN_POWER = (8.0, 7.4, 6.4)


@dataclass
class LightSpec:
    """One lighting in three forms (:func:`spec_envmap`, :func:`spec_sh`, :func:`spec_reference`): an optional HDR
    ``env`` file (``None``: the player's procedural sky without its sun), plus an optional sun disk ``sun_dir (3,)``
    of ``sun_half_angle`` radians and RGB ``sun_power`` (``int L dOmega`` over the disk)."""

    name: str
    env: str | None = None
    sun_dir: np.ndarray | None = None
    sun_half_angle: float = 0.0
    sun_power: np.ndarray | None = None

    @property
    def sun_radiance(self) -> np.ndarray:
        assert self.sun_power is not None
        return self.sun_power / (2 * math.pi * (1.0 - math.cos(self.sun_half_angle)))

    @property
    def source(self) -> str:
        base = self.env or "procedural sky without its sun (CIE clear sky + ground)"
        if self.sun_dir is None:
            return base
        return (f"{base} + sun disk (half-angle {math.degrees(self.sun_half_angle):.2f} deg, power "
                f"{np.round(self.sun_power, 2).tolist()}, direction {np.round(self.sun_dir, 3).tolist()})")


def light_spec(light: str, env: str | Path | None = None, sun_size_deg: float = SUN_HALF_ANGLE_DEG,
               sun_power: float | tuple[float, float, float] | None = None) -> LightSpec:
    """The :class:`LightSpec` of ``prt compare --light`` (``"smooth"`` or ``"sun"``; ``"sky"`` is handled by
    :func:`compare_lights`). The sun direction is the player's (:data:`~prt_torch.player.lighting.
    DEFAULT_SUN_DIRECTION`); ``sun_power``: a scalar (times the default colour's ratios) or RGB."""
    from prt_torch.player.lighting import DEFAULT_SUN_DIRECTION

    check(light in ("smooth", "sun"), f"--light must be one of {', '.join(LIGHTS)}, got {light!r}")
    check(math.isfinite(sun_size_deg) and 0.05 <= sun_size_deg <= 30,
          f"--sun-size must be in [0.05, 30] degrees, got {sun_size_deg}")
    envs = str(env) if env is not None and str(env) not in ("", "sky") else None
    if envs is not None:
        check(Path(envs).is_file(), f"environment map not found: {envs}")
    if light == "smooth":
        return LightSpec("smooth", envs)
    p = np.asarray(SUN_POWER, dtype=np.float64)
    if sun_power is not None:
        sp = np.asarray(sun_power, dtype=np.float64).reshape(-1)
        check(sp.size in (1, 3) and bool(np.isfinite(sp).all()) and bool((sp > 0).all()),
              f"--sun-power must be one positive number or three, got {sun_power}")
        p = p / p.max() * sp[0] if sp.size == 1 else sp
    d = np.asarray(DEFAULT_SUN_DIRECTION, dtype=np.float64)
    return LightSpec("sun", envs, d / np.linalg.norm(d), math.radians(sun_size_deg), p)


def sky_spec(env: str | Path | None = None) -> LightSpec:
    """The :class:`LightSpec` of ``--light sky``: the player's default procedural sky and its sun (a disk of the
    player's half-angle and power, :data:`~prt_torch.player.lighting.DEFAULT_SUN_COLOR`), or the ``env`` file alone
    (for methods that need the lighting as a map, e.g. ``sg_vct``)."""
    from prt_torch.light.sources import sky_sh
    from prt_torch.player.lighting import DEFAULT_SUN_COLOR, DEFAULT_SUN_DIRECTION

    if env is not None and str(env) not in ("", "sky"):
        return LightSpec("sky", str(env))
    half = float(inspect.signature(sky_sh).parameters["sun_half_angle"].default)
    d = np.asarray(DEFAULT_SUN_DIRECTION, dtype=np.float64)
    return LightSpec("sky", None, d / np.linalg.norm(d), half, np.asarray(DEFAULT_SUN_COLOR, dtype=np.float64))


def _base_envmap(spec: LightSpec, height: int) -> Any:
    from prt_torch.light.envmap import load_envmap
    from prt_torch.light.sources import sky_envmap
    from prt_torch.player.lighting import DEFAULT_SUN_DIRECTION

    if spec.env is not None:
        return load_envmap(spec.env)
    return sky_envmap(np.asarray(DEFAULT_SUN_DIRECTION) / np.linalg.norm(DEFAULT_SUN_DIRECTION), height=height)


def spec_envmap(spec: LightSpec, height: int | None = None) -> Any:
    """The lighting as one lat-long (or the file's) :class:`~prt_torch.light.envmap.EnvMap`, the sun disk
    rasterised by :func:`prt_torch.sg.shading.add_sun_disk`. The procedural sky's ``height`` defaults to 512 rows,
    more (up to 2048) so that the disk spans >= 3 pixels in radius (:func:`~prt_torch.sg.shading.sun_map_height`)."""
    from prt_torch.sg.shading import add_sun_disk, sun_map_height

    if height is None:
        height = sun_map_height(spec.sun_half_angle) if spec.sun_dir is not None else 512
    env = _base_envmap(spec, height)
    if spec.sun_dir is None:
        return env
    return add_sun_disk(env, spec.sun_dir, spec.sun_half_angle, spec.sun_power, source=spec.source)


def spec_sh(spec: LightSpec, order: int) -> np.ndarray:
    """SH ``(C, 3)`` of the lighting: the base map projected, plus the sun as an SH disk light."""
    from prt_torch.light.envmap import envmap_to_sh
    from prt_torch.light.sources import directional_light_sh

    sh = envmap_to_sh(_base_envmap(spec, 128), order)
    if spec.sun_dir is not None:
        sh = sh + directional_light_sh(spec.sun_dir, spec.sun_power, order, spec.sun_half_angle)
    return sh


def spec_reference(spec: LightSpec) -> ReferenceLight:
    """The lighting at full resolution: the base map's radiance function (:func:`sky_radiance`, the procedural sky
    evaluated at each ray, without its sun, or the file's nearest pixel), plus the sun as a disk light sampled
    with its own rays."""
    base = envmap_reference(spec.env).radiance if spec.env is not None else sky_radiance()
    disks = [] if spec.sun_dir is None else [(spec.sun_dir, spec.sun_half_angle, spec.sun_radiance)]
    return ReferenceLight(base, [], spec.source, disks)


def silhouette_mask(positions: np.ndarray, frames: np.ndarray, eye: np.ndarray) -> np.ndarray:
    """``(..., V)`` bool: vertices whose normal faces the camera, ``n . (eye - p) > 0`` (``positions (..., V, 3)``
    world, ``frames (..., V, 3, 3)`` rows ``(t, b, n)``, ``eye (3,)``).

    **The silhouette rule** of ``prt compare``: a vertex seen from below its horizon (``n . v <= 0``) has radiance 0
    in EVERY row and in the reference (the analytic BRDFs vanish there, so the Monte-Carlo reference is 0 by itself;
    an RPO's view factor, a least-squares SH fit over the upper hemisphere, extrapolates, and the shipping shader has
    no clamp). Such vertices lie on the silhouette rim, where the rasteriser interpolates them into front-facing
    triangles."""
    view = np.asarray(eye, dtype=np.float64) - np.asarray(positions, dtype=np.float64)
    return np.einsum("...i,...i->...", np.asarray(frames, dtype=np.float64)[..., 2, :], view) > 0


def front_facing(positions: np.ndarray, frames: np.ndarray, eye: np.ndarray) -> np.ndarray:
    """``(V,)`` bool: :func:`silhouette_mask` of one frame. Only these vertices are compared with the reference per
    vertex (behind the horizon every row is 0 by the silhouette rule, or, without it, the RPO extrapolates)."""
    return silhouette_mask(positions, frames, eye)


@dataclass
class ReferencePair:
    """Two independent estimates ``a``, ``b`` ``{brdf: (V, 3)}`` and their mean ``mean``."""

    a: dict[str, np.ndarray]
    b: dict[str, np.ndarray]

    @property
    def mean(self) -> dict[str, np.ndarray]:
        return {k: 0.5 * (self.a[k] + self.b[k]) for k in self.a}


def reference_pair(positions: np.ndarray, frames: np.ndarray, faces: np.ndarray, eye: np.ndarray,
                   light: ReferenceLight, brdfs: Mapping[str, Any], n_rays: int, offset: float,
                   seeds: tuple[int, int] = (101, 202)) -> ReferencePair:
    """Two independent :func:`reference_radiance` estimates (seeds ``seeds``)."""
    return ReferencePair(*(reference_radiance(positions, frames, faces, eye, light, brdfs, n_rays, s, offset)
                           for s in seeds))


# -- the lighting of one ``prt compare`` run, whole and split ---------------------------------------------------------


@dataclass
class CompareLights:
    """The lighting of one ``prt compare`` run in every form it is used:

    * ``spec``: the :class:`LightSpec` (for methods that need the lighting as a map, e.g. ``sg_vct``);
    * ``lighting``: the whole lighting on the SH / ZH-lobe path (the player's, windowed): every method's own row;
    * ``peaks``: the :class:`~prt_torch.sg.split.PeakLight` list (empty: no ``+peaks`` rows) and ``residual`` the
      rest of the light on the same path (``None`` without peaks): the ``+peaks`` rows;
    * ``reference``: the :class:`ReferenceLight` of the Monte-Carlo reference, the same for every row: the residual
      at full resolution + every peak as a disk of the peak's angular radius (:func:`split_reference`).
    """

    spec: LightSpec
    lighting: Any
    peaks: list[Any]
    residual: Any
    reference: ReferenceLight
    residual_window: bool = True


def compare_lights(light: str, env: str | Path | None, order: int, peaks: int | str = "auto",
                   residual_window: bool | None = None, sun_size: float | None = None,
                   sun_power: float | None = None) -> CompareLights:
    """The :class:`CompareLights` of ``prt compare --light LIGHT [--env FILE] --peaks auto|0|K``.

    * ``sky``: the player's lighting (``env`` or the procedural sky + its sun); peaks + residual by
      :func:`prt_torch.player.peaks.load_peak_lighting` (``residual_window``: its sinc window on the residual, default
      the player's :data:`~prt_torch.player.peaks.RESIDUAL_WINDOW`); the
      reference is the split (``peaks=0``: the ``"auto"`` split, so that every ``--peaks`` is scored against the same
      low-noise reference).
    * ``sun``: :func:`light_spec`'s base (``env`` or the sky without its sun) + its sun disk; the disk is the peak,
      the base the residual (projected at order ``order``, ZH lobes); the reference :func:`spec_reference`.
    * ``smooth``: no peak (``peaks`` must be ``"auto"`` or 0); the reference :func:`spec_reference`.
    """
    from prt_torch.light.envmap import envmap_to_sh
    from prt_torch.player.lighting import lighting_from_sh, load_lighting
    from prt_torch.player.peaks import AUTO, RESIDUAL_WINDOW, check_peaks_arg, load_peak_lighting, load_split
    from prt_torch.sg.split import PeakLight

    residual_window = RESIDUAL_WINDOW if residual_window is None else bool(residual_window)
    k = check_peaks_arg(peaks)
    check(light in LIGHTS, f"--light must be one of {', '.join(LIGHTS)}, got {light!r}")
    if light == "sky":
        spec = sky_spec(env)
        lighting = load_lighting(env, order)
        if k == 0:
            return CompareLights(spec, lighting, [], None, split_reference(load_split(env, AUTO), env),
                                 residual_window)
        pl = load_peak_lighting(env, order, k, window=residual_window)
        return CompareLights(spec, lighting, list(pl.peaks), pl.lighting if pl.peaks else None,
                             split_reference(pl.split, env), residual_window)
    check(light == "sun" or k in (AUTO, 0), f"--peaks {k}: --light smooth has no peak light (use --light sky or sun)")
    spec = light_spec(light, env, *(() if sun_size is None else (sun_size,)), sun_power=sun_power)
    lighting = lighting_from_sh(spec_sh(spec, order), 3, source=spec.source)
    ref = spec_reference(spec)
    if spec.sun_dir is None or k == 0:
        return CompareLights(spec, lighting, [], None, ref, residual_window)
    peak = PeakLight(spec.sun_dir, spec.sun_half_angle, spec.sun_radiance)
    base = spec.env or "procedural sky without its sun"
    residual = lighting_from_sh(envmap_to_sh(_base_envmap(spec, 128), order), 3, source=f"{base} (residual)",
                                window=residual_window)
    return CompareLights(spec, lighting, [peak], residual, ref, residual_window)

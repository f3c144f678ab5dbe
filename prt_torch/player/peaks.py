"""The player's peak lights (issue 27): the lighting split into peaks + residual, and the three peak visibilities.

**Lighting** (:func:`load_peak_lighting`): the player's lighting (``env`` a map file, or the procedural sky) split
by :mod:`prt_torch.sg.split`: up to ``K`` peak lights (the sky's sun by construction; a map's by seed 004's
detection) and the residual, which goes through the SH / ZH-lobe path exactly as the whole lighting did
(:func:`~prt_torch.player.lighting.lighting_from_sh`). ``peaks="auto"``: the sky's sun, or up to
:data:`~prt_torch.sg.split.DEFAULT_PEAKS` of a map's; ``0``: no split (the whole lighting on the SH path, as before).

**Visibility** of each peak's disc per vertex, ``(B, V, P)`` in ``[0, 1]`` (:data:`PEAK_KINDS`, one interface,
:class:`PeakVisibility`):

=============  ======================================================================================================
``exact``      Embree rays to stratified disc samples (:func:`prt_torch.bake.peaks.exact_peak_visibility`): the oracle
``spheres``    the run's blocker spheres, analytic cone-sphere occlusion (:func:`prt_torch.blockers.cones.
               sphere_peak_visibility`, one compiled pass), no bake
``learned``    the learned peak blockers (``peak_blockers.npz``, :mod:`prt_torch.models.peak_blockers`): the same
               kernel with spheres fitted to the bake's exact peak visibility
=============  ======================================================================================================

numpy + numba + Embree only (no torch): the player imports this.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from prt_torch.blockers.cones import sphere_visibility_soa
from prt_torch.errors import PrtError, check
from prt_torch.player.lighting import DEFAULT_SUN_COLOR, DEFAULT_SUN_DIRECTION, Lighting, lighting_from_sh
from prt_torch.shapes import check_shape

#: the peak visibilities (module doc), in the order of ``prt compare``'s rows
PEAK_KINDS = ("exact", "spheres", "learned")
#: ``--peaks auto``
AUTO = "auto"
#: the sinc window on the residual's SH (with peaks): off. The window damps the ringing of a truncated sun; without
#: the sun the residual is smooth and the window only blurs it (measured with ``prt compare`` on the demo run,
#: procedural sky, image PSNR vs the reference, diffuse / glossy: ``sh_truth+peaks_exact`` 43.66 / 33.33 dB windowed,
#: 51.89 / 33.58 dB not; ``learned_mlp+peaks_learned`` 32.31 / 30.87 vs 32.39 / 31.06). The whole lighting without
#: peaks (``--peaks 0``) keeps it.
RESIDUAL_WINDOW = False


@dataclass
class PeakLighting:
    """The player's lighting as peaks + residual: ``lighting`` the residual's ZH lobes (the SH path), ``peaks``
    the :class:`~prt_torch.sg.split.PeakLight` list (strongest first; empty: no split), ``split`` the
    :class:`~prt_torch.sg.split.LightSplit` (``None`` without peaks)."""

    lighting: Lighting
    peaks: list[Any]
    split: Any = None

    @property
    def directions(self) -> np.ndarray:
        """``(P, 3)`` float64 unit peak directions."""
        return np.array([p.direction for p in self.peaks], dtype=np.float64).reshape(-1, 3)

    @property
    def angular_radii(self) -> np.ndarray:
        """``(P,)`` float64 half-angles (radians)."""
        return np.array([p.angular_radius for p in self.peaks], dtype=np.float64)

    @property
    def powers(self) -> np.ndarray:
        """``(P, 3)`` float64 RGB powers (radiance x solid angle)."""
        return np.array([p.power for p in self.peaks], dtype=np.float64).reshape(-1, 3)

    def rotated_about_z(self, angle: float) -> PeakLighting:
        """The same lighting rotated by ``angle`` radians about the world z (up) axis (peaks and residual)."""
        from prt_torch.sg.split import PeakLight

        c, s = math.cos(angle), math.sin(angle)
        R = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
        peaks = [PeakLight(R @ p.direction, p.angular_radius, p.radiance) for p in self.peaks]
        return PeakLighting(self.lighting.rotated_about_z(angle), peaks, self.split)

    def to_dict(self) -> dict[str, Any]:
        """``{"peaks": [...]}``, the ``compare.json`` schema (:meth:`~prt_torch.sg.split.PeakLight.to_dict`)."""
        return {"peaks": [p.to_dict() for p in self.peaks]}


def check_peaks_arg(peaks: object) -> int | str:
    """``"auto"`` or an int in ``0..MAX_PEAKS`` (``--peaks auto|0|K``), else a one-line :class:`PrtError`."""
    from prt_torch.sg.split import check_peak_count

    if isinstance(peaks, str):
        if peaks == AUTO:
            return AUTO
        check(peaks.isdigit(), f"--peaks must be 'auto' or an integer 0..4, got {peaks!r}")
        peaks = int(peaks)
    return check_peak_count(peaks, "--peaks")


def is_sky(env: str | os.PathLike[str] | None) -> bool:
    """Whether ``env`` names the procedural sky (``None``, ``""`` or ``"sky"``)."""
    return env is None or str(env) in ("", "sky")


def load_split(env: str | os.PathLike[str] | None, peaks: int | str = AUTO, sun_angular_radius: float | None = None,
               ) -> Any:
    """The :class:`~prt_torch.sg.split.LightSplit` of the player's lighting (``peaks``: ``"auto"`` or ``K >= 1``).

    The procedural sky's sun is the player's (:data:`~prt_torch.player.lighting.DEFAULT_SUN_DIRECTION`,
    :data:`~prt_torch.player.lighting.DEFAULT_SUN_COLOR`) with ``sun_angular_radius`` (default the real sun's);
    a map's peaks are detected (at most ``peaks``, ``"auto"``: :data:`~prt_torch.sg.split.DEFAULT_PEAKS`)."""
    from prt_torch.sg.split import DEFAULT_PEAKS, SUN_ANGULAR_RADIUS, split_envmap, split_sky

    k = check_peaks_arg(peaks)
    if is_sky(env):
        sun = np.asarray(DEFAULT_SUN_DIRECTION, dtype=np.float64)
        return split_sky(sun / np.linalg.norm(sun), DEFAULT_SUN_COLOR,
                         sun_angular_radius=SUN_ANGULAR_RADIUS if sun_angular_radius is None else sun_angular_radius)
    from prt_torch.light.envmap import load_envmap

    path = Path(str(env))
    check(path.is_file(), f"environment map not found: {path}")
    return split_envmap(load_envmap(path), DEFAULT_PEAKS if k == AUTO else int(k),
                        angular_radius=sun_angular_radius)


def load_peak_lighting(env: str | os.PathLike[str] | None, order: int, peaks: int | str = AUTO, n_lobes: int = 3,
                       window: bool | None = None, sun_angular_radius: float | None = None) -> PeakLighting:
    """The player's lighting as :class:`PeakLighting` (module doc): ``peaks=0`` is the whole lighting on the SH path
    (:func:`~prt_torch.player.lighting.load_lighting`, no peaks, windowed); otherwise the residual's lobes (``window``
    default :data:`RESIDUAL_WINDOW`) and the peaks."""
    from prt_torch.light.envmap import envmap_to_sh
    from prt_torch.player.lighting import load_lighting

    k = check_peaks_arg(peaks)
    if k == 0:
        return PeakLighting(load_lighting(env, order, n_lobes, window=True if window is None else window), [], None)
    window = RESIDUAL_WINDOW if window is None else window
    split = load_split(env, k, sun_angular_radius)
    if isinstance(k, int) and len(split.peaks) > k:
        split.peaks = split.peaks[:k]
    source = ("procedural sky" if is_sky(env) else str(env)) + f" without its {len(split.peaks)} peak(s)"
    lighting = lighting_from_sh(envmap_to_sh(split.residual, order), n_lobes, source=source, window=window)
    return PeakLighting(lighting, list(split.peaks), split)


# -- visibility ------------------------------------------------------------------------------------------------------


class PeakVisibility:
    """One way to compute peak visibility: ``__call__(positions (B, V, 3), normals (B, V, 3), skin (B, J, 4, 4) or
    None, directions (P, 3), angular_radii (P,)) -> (B, V, P)`` float32 in ``[0, 1]``; ``kind`` one of
    :data:`PEAK_KINDS`; :meth:`bytes` its run-time data beyond the character."""

    kind: str = ""
    #: whether a vertex's result depends on its own position and normal only (any vertex order gives the same rows)
    per_vertex: bool = False

    def __call__(self, positions: np.ndarray, normals: np.ndarray, skin: np.ndarray | None, directions: np.ndarray,
                 angular_radii: np.ndarray) -> np.ndarray:
        raise NotImplementedError

    def vertex_last(self, positions: np.ndarray, normals: np.ndarray, skin: np.ndarray | None,
                    directions: np.ndarray, angular_radii: np.ndarray, threads: bool = True) -> np.ndarray:
        """The same ``(B, V, P)`` from the player's vertex-last ``positions, normals (B, 3, V)``
        (:class:`~prt_torch.player.posing.PoseBatch` rows); ``threads``: a compiled kernel's numba threads
        (``False``: the calling thread only)."""
        pos, nrm = (np.ascontiguousarray(np.swapaxes(x, 1, 2)) for x in (positions, normals))
        return self(pos, nrm, skin, directions, angular_radii)

    def bytes(self) -> int:
        return 0


class ExactPeaks(PeakVisibility):
    """``exact``: Embree rays to ``side x side`` stratified disc samples against the posed mesh ``faces`` (and
    ``extra`` static triangles, e.g. a floor: ``(vertices (N, 3), faces (M, 3))``), origins offset by ``offset``."""

    kind = "exact"

    def __init__(self, faces: np.ndarray, offset: float, side: int | None = None,
                 extra: tuple[np.ndarray, np.ndarray] | None = None) -> None:
        from prt_torch.bake.peaks import DEFAULT_DISC_SIDE

        self.faces = np.asarray(faces, dtype=np.int64)
        self.offset = float(offset)
        self.side = DEFAULT_DISC_SIDE if side is None else int(side)
        self.extra = extra

    def __call__(self, positions: np.ndarray, normals: np.ndarray, skin: np.ndarray | None, directions: np.ndarray,
                 angular_radii: np.ndarray) -> np.ndarray:
        from prt_torch.bake.embree import RayScene
        from prt_torch.bake.peaks import exact_peak_visibility

        pos = np.asarray(positions, dtype=np.float32)
        check_shape(pos, "B V 3", name="exact peaks: positions")
        out = np.empty((*pos.shape[:2], len(directions)), np.float32)
        for b in range(pos.shape[0]):  # B posed meshes: one Embree scene each
            verts, faces = pos[b], self.faces
            if self.extra is not None:
                ev, ef = self.extra
                faces = np.concatenate([faces, np.asarray(ef, np.int64) + len(verts)])
                verts = np.concatenate([verts, np.asarray(ev, np.float32)])
            scene = RayScene(verts, faces)
            out[b] = exact_peak_visibility(pos[b], normals[b], directions, angular_radii, self.offset, scene=scene,
                                           side=self.side)
        return out


class SpherePeaks(PeakVisibility):
    """``spheres``: a :class:`~prt_torch.blockers.spheres.SphereSet` carried by the bones (``skin``), the analytic
    cone-sphere kernel (numpy, one compiled pass)."""

    kind = "spheres"
    per_vertex = True

    def __init__(self, spheres: Any) -> None:
        self.spheres = spheres

    @property
    def blockers(self) -> Any:
        """The blocker set (a :class:`~prt_torch.blockers.spheres.SphereSet` here): what occludes this character's
        peaks for the others and the floor in a scene (:mod:`prt_torch.player.scene`)."""
        return self.spheres

    def __call__(self, positions: np.ndarray, normals: np.ndarray, skin: np.ndarray | None, directions: np.ndarray,
                 angular_radii: np.ndarray) -> np.ndarray:
        from prt_torch.blockers.cones import sphere_peak_visibility
        from prt_torch.blockers.spheres import pose_spheres

        check(skin is not None, f"{self.kind} peak visibility needs the skinning matrices (a skinned character)")
        centers = pose_spheres(self.spheres, skin)
        pos = np.ascontiguousarray(positions, dtype=np.float32)
        return sphere_peak_visibility(pos, np.ascontiguousarray(normals, dtype=np.float32), centers,
                                      self.spheres.radius.astype(np.float32),
                                      np.ascontiguousarray(directions, dtype=np.float32),
                                      np.asarray(angular_radii, dtype=np.float32)).astype(np.float32, copy=False)

    def vertex_last(self, positions: np.ndarray, normals: np.ndarray, skin: np.ndarray | None,
                    directions: np.ndarray, angular_radii: np.ndarray, threads: bool = True) -> np.ndarray:
        """The player's path: :func:`sphere_visibility_soa` (the same kernel fused per vertex, vertex-last input)."""
        from prt_torch.blockers.spheres import pose_spheres

        check(skin is not None, f"{self.kind} peak visibility needs the skinning matrices (a skinned character)")
        return sphere_visibility_soa(positions, normals, pose_spheres(self.spheres, skin), self.spheres.radius,
                                     directions, angular_radii, threads=threads)

    def bytes(self) -> int:
        return int(self.spheres.center.nbytes + self.spheres.radius.nbytes + self.spheres.bone.nbytes)


class LearnedPeaks(SpherePeaks):
    """``learned``: the learned peak blockers (``peak_blockers.npz``: spheres through the same kernel, or capsules,
    a :class:`~prt_torch.blockers.capsules.CapsuleSet`, through the capsule kernel)."""

    kind = "learned"

    def __init__(self, blockers: Any) -> None:
        from prt_torch.blockers.capsules import CapsuleSet

        #: the learned capsules (``None``: learned spheres, then :attr:`spheres`)
        self.capsules = blockers if isinstance(blockers, CapsuleSet) else None
        super().__init__(None if self.capsules is not None else blockers)

    @property
    def blockers(self) -> Any:
        """The learned capsules, or the learned spheres."""
        return self.capsules if self.capsules is not None else self.spheres

    def __call__(self, positions: np.ndarray, normals: np.ndarray, skin: np.ndarray | None, directions: np.ndarray,
                 angular_radii: np.ndarray) -> np.ndarray:
        if self.capsules is None:
            return super().__call__(positions, normals, skin, directions, angular_radii)
        pos = np.asarray(positions, dtype=np.float32)
        check_shape(pos, "B V 3", name="learned peaks: positions")
        return self.vertex_last(pos.transpose(0, 2, 1), np.asarray(normals, np.float32).transpose(0, 2, 1), skin,
                                directions, angular_radii, threads=False)

    def vertex_last(self, positions: np.ndarray, normals: np.ndarray, skin: np.ndarray | None,
                    directions: np.ndarray, angular_radii: np.ndarray, threads: bool = True) -> np.ndarray:
        """The player's path: the sphere or the capsule kernel, compiled, on vertex-last input."""
        from prt_torch.blockers.capsules import pose_capsules
        from prt_torch.blockers.cones import capsule_visibility_soa

        if self.capsules is None:
            return super().vertex_last(positions, normals, skin, directions, angular_radii, threads)
        check(skin is not None, f"{self.kind} peak visibility needs the skinning matrices (a skinned character)")
        a, b = pose_capsules(self.capsules, skin)
        return capsule_visibility_soa(positions, normals, a, b, self.capsules.radius, directions, angular_radii,
                                      threads=threads)

    def bytes(self) -> int:
        c = self.capsules
        return super().bytes() if c is None else int(c.a.nbytes + c.b.nbytes + c.radius.nbytes + c.bone.nbytes)


def learned_blockers_path(run: Any) -> Path | None:
    """The run's learned peak blockers (``RunDir.peak_blockers_path``), or ``None`` when it has none."""
    p = run.peak_blockers_path
    return p if p.is_file() else None


def peak_visibility(kind: str, run: Any, character: Any, offset: float | None = None,
                    spheres: Any = None) -> PeakVisibility:
    """The :class:`PeakVisibility` of ``kind`` for a run (:class:`~prt_torch.rundir.RunDir`): ``exact`` traces the
    character's mesh (``offset``: the bake's ray offset), ``spheres`` the run's blocker spheres (``spheres``, or the
    exported ``blockers.npz``), ``learned`` the run's ``peak_blockers.npz`` (one-line errors when missing)."""
    from prt_torch.blockers.spheres import SphereSet

    check(kind in PEAK_KINDS, f"unknown peak visibility {kind!r}: expected one of {', '.join(PEAK_KINDS)}")
    if kind == "exact":
        check(offset is not None, "exact peak visibility needs the bake's ray offset")
        return ExactPeaks(character.faces, float(offset))  # type: ignore[arg-type]
    if kind == "spheres":
        if spheres is None:
            p = run.blockers_path
            check(p.is_file(), f"{run.path}: no blocker spheres: run `prt export {run.path}`")
            spheres = SphereSet.load(p)
        return SpherePeaks(spheres)
    p = learned_blockers_path(run)
    if p is None:
        raise PrtError(f"{run.path}: no learned peak blockers ({run.peak_blockers_path.name}): bake with "
                       f"`bake.peaks` and run `prt train`")
    from prt_torch.blockers.capsules import load_blocker_set

    return LearnedPeaks(load_blocker_set(p))

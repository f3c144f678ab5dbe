"""The run-time player: clip -> numpy FK/LBS/frames -> ONNX Runtime visibility + RPO shading ->
colours -> pyvista (offscreen PNG/MP4 or a window). numpy + onnxruntime + pyvista only: importing
or running it never imports torch or the training code.

Per frame (``Player.compute``)::

    local (B, J, 4, 4) --FK--> skin (B, J, 4, 4) --LBS--> positions, normals (B, 3, V)
        --cluster axes--> frames (B, 9, V);  pose features (B, A)   (prt_torch.player.posing, vertex-last)
    [compiled] the default on the CPU (prt_torch.player.compiled): ORT latent.onnx(pose) -> z, then ONE compiled
             pass decodes and shades each vertex tile while it is in cache -> radiance (B, V, 3) (= fused.onnx within
             the export's parity tolerance); its posing is compiled too (two passes: joints, then vertices)
    [fused]  ORT fused.onnx(pose, frames, view dirs, lobes, RPO) -> radiance (B, V, 3)
    [split]  ORT visibility.onnx(pose) -> (B, V, C);  ORT shading.onnx(...) -> radiance
    [overlap] split, with visibility.onnx running on a worker thread while numpy poses (compute_overlapped)
    [fused_peaks] ORT fused_peaks.onnx(fused inputs, positions, skin, peaks, BRDF) -> radiance with the peaks' term
             and their learned shadows in the same graph (prt_torch.export.peaks_graph; no [peaks] step after it)
    [peaks]  + sum_p E_p f_r(l_p, v) max(n.l_p, 0) V_p: each peak light of the lighting (its sun) with its soft
             shadow V_p (B, V, P) from the run's peak blockers (prt_torch.player.peaks), after the graph(s)
    B > 1 (a crowd): ONE batched call of every graph for all B characters (same or different clips)

Peak lights (issue 27): the lighting is split into up to K peak lights and the residual (``peaks="auto"``: the sky's
sun, or a map's detected peaks; ``0``: no split, the whole lighting on the SH path as before). The residual goes
through the graphs (:attr:`Player.lighting` is the residual then); each peak adds its direct term with the analytic
BRDF the selected RPO was built from and the visible fraction of its disc (:attr:`Player.peak_source`, a
:class:`~prt_torch.player.peaks.PeakVisibility`: by default the run's learned peak blockers, else its blocker
spheres, else none - the peaks then cast no shadow, with a warning).

Vertex order: a format /3 export's fused graph takes and returns its vertex axes in the CLUSTER-SORTED order
``bundle.vertex_order`` (position i holds original vertex vertex_order[i]); the Poser poses in that order
(weights permuted once), and everything the Player returns (radiance, PoseBatch fields, visibility) is in the
ORIGINAL vertex order: only the radiance (B, V, 3) is put back per frame.
    radiance --tone map (exposure, Reinhard white), gamma--> uint8 colours

Embedding::

    p = Player("runs/demo", env="uffizi.hdr", brdf="phong")
    result = p.play("walk", out="walk.mp4")           # or png_dir=..., max_frames=..., show=True
    img = p.render_frame(*p.compute(p.clip_locals("walk")[:1]))
"""

from __future__ import annotations

import os
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from prt_torch.blockers.cones import sphere_visibility_soa
from prt_torch.brdf.direct import brdf_code, peak_radiance_soa
from prt_torch.errors import PrtError, check, warn
from prt_torch.player.bundle import RPOTensors, RunBundle
from prt_torch.player.lighting import Lighting, hemisphere_visibility
from prt_torch.player.material import SurfaceAlbedo, brdf_names, select_rpo, surface_albedo
from prt_torch.player.peaks import (
    AUTO,
    PEAK_KINDS,
    PeakLighting,
    PeakVisibility,
    learned_blockers_path,
    load_peak_lighting,
    peak_visibility,
)
from prt_torch.player.posing import PoseBatch, Poser
from prt_torch.player.timing import FrameTimer
from prt_torch.player.tonemap import ToneMap, auto_tonemap
from prt_torch.rig.clip import Clip
from prt_torch.rundir import RunDir
from prt_torch.runtime.session import OrtGraph

GRAPH_MODES = ("compiled", "fused", "split", "overlap", "fused_peaks")
#: the graph modes that play a graph in the export's cluster-sorted vertex order
CLUSTER_ORDER_MODES = ("compiled", "fused", "fused_peaks")


def default_graph(bundle: RunBundle, device: str) -> str:
    """The graph mode a player plays when none is asked for: ``compiled`` on the CPU when the export ships its data
    (:func:`prt_torch.player.compiled.has_compiled_path`), else ``fused``."""
    from prt_torch.player.compiled import has_compiled_path

    return "compiled" if device == "cpu" and has_compiled_path(bundle) else "fused"


@dataclass
class PlayResult:
    """What :meth:`Player.play` did: frames, timing summary, written files."""

    frames: int
    summary: dict[str, Any]
    outputs: list[Path]


#: the default camera: azimuth (radians, 0 = in front, along -y) and elevation above the horizon
CAMERA_AZIMUTH, CAMERA_ELEVATION = 0.0, 0.2
#: camera distance from the centre, in rest-pose bounding-box diagonals
CAMERA_DISTANCE = 1.9
#: :meth:`Player.play`'s cameras: the follow camera (:mod:`prt_torch.player.follow`) or the rest pose's fixed one
CAMERA_MODES = ("follow", "fixed")


def camera_target(rest_vertices: np.ndarray) -> tuple[np.ndarray, float]:
    """``(center (3,) float32, radius)``: the rest-pose bounding-box centre and diagonal the camera orbits."""
    rest = np.asarray(rest_vertices)
    lo, hi = rest.min(0), rest.max(0)
    return (0.5 * (lo + hi)).astype(np.float32), float(np.linalg.norm(hi - lo))


def camera_eye(center: np.ndarray, radius: float, azimuth: float = CAMERA_AZIMUTH,
               elevation: float = CAMERA_ELEVATION) -> np.ndarray:
    """The player's camera position (world, float32): orbiting ``center`` at ``CAMERA_DISTANCE * radius``,
    in front (-y) at azimuth 0, ``elevation`` radians up."""
    a, e = azimuth, elevation
    d = np.array([np.sin(a) * np.cos(e), -np.cos(a) * np.cos(e), np.sin(e)])
    return (np.asarray(center) + CAMERA_DISTANCE * radius * d).astype(np.float32)


def facing_azimuth(positions: np.ndarray, faces: np.ndarray, chunk: int = 64) -> float:
    """The camera azimuth (radians, :func:`camera_eye`'s convention) that faces the FRONT side of a surface that
    moves (a cloth): the horizontal part of its area-weighted mean face normal over every frame of
    ``positions (F, V, 3)`` (``faces (T, 3)``, counter-clockwise = front). A closed surface (a body) sums to ~0
    and keeps :data:`CAMERA_AZIMUTH`, so the body + cape subject is seen from the cape's side."""
    pos = np.asarray(positions, dtype=np.float32)
    pos = pos.reshape(-1, *pos.shape[-2:])
    f = np.asarray(faces, dtype=np.int64)
    n_sum, area = np.zeros(3), 0.0
    for i in range(0, pos.shape[0], chunk):  # frame chunks: bounded memory (F x T x 3 at once can be GBs)
        p = pos[i:i + chunk]
        cr = np.cross(p[:, f[:, 1]] - p[:, f[:, 0]], p[:, f[:, 2]] - p[:, f[:, 0]])
        n_sum += cr.sum(axis=(0, 1), dtype=np.float64)
        area += float(np.linalg.norm(cr, axis=-1).sum(dtype=np.float64))
    h = n_sum[:2]
    if np.linalg.norm(h) <= 0.05 * max(area, 1e-30):  # no side faces the camera more than another
        return CAMERA_AZIMUTH
    return float(np.arctan2(h[0], -h[1]))  # camera_eye's direction (sin a, -cos a) along the mean normal


def sequence_view(positions: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, float, float]:
    """``(center, radius, azimuth)`` of the camera for a deformable sequence ``positions (F, V, 3)``: the
    :func:`camera_target` box of every position of every frame (a flag blown sideways leaves its rest box) and
    :func:`facing_azimuth`. The player and ``prt compare`` both frame a cloth run by this rule."""
    center, radius = camera_target(np.asarray(positions).reshape(-1, 3))
    return center, radius, facing_azimuth(positions, faces)


class Player:
    """Plays clips of an exported run with ONNX Runtime (see the module docstring).

    Args:
        run_dir: exported run directory.
        env: HDR environment map path, or ``None`` for the procedural sun + sky.
        brdf: BRDF name of the run's RPO catalogue (or an RPO ``.npz``, or ``material``); ``None``: the character's
            own material when it has one (:attr:`shades_material`), else the catalogue's first.
        graph: ``"compiled"`` (the compiled frame path: a 40 kB ORT graph, then one numba pass; the default on the
            CPU when the export ships it), ``"fused"`` (one ORT call per frame), ``"split"`` (visibility then
            shading), ``"overlap"`` (split, with the visibility call running on a worker thread during the numpy
            posing: :meth:`compute_overlapped`) or ``"fused_peaks"``; ``None``: :func:`default_graph`.
        threads: onnxruntime intra-op threads.
        window_size: render size in pixels.
        exposure: a fixed :class:`~prt_torch.player.tonemap.ToneMap`; ``None`` picks one from the first frame.
        n_lobes: ZH lobes fitted to the lighting.
        blas_threads: BLAS threads for the numpy posing path (its GEMMs are tiny; 1 avoids thread
            start-up and busy-waiting next to onnxruntime's threads). ``None`` leaves BLAS alone.
            The limit applies process-wide while the player is open (undone by :meth:`close`).
        spinning: let onnxruntime's idle intra-op threads busy-wait (faster ORT calls on an otherwise
            idle machine; steals a core from the numpy posing and from other processes on a busy one).
        device: ``"cpu"`` or ``"cuda"`` (onnxruntime's CUDA provider: ``onnxruntime-gpu``, extra ``gpu``).
        crowd_chunk: characters per fused call for a crowd (``B`` > this: several calls of this many); ``None``:
            the whole crowd in ONE call. On a CPU the shading's per-vertex intermediates grow with ``B`` and leave
            the cache, so a few characters per call can beat one call (``prt bench play --crowd-chunk`` measures).
        peaks: the peak lights split off the lighting (module doc): ``"auto"``, ``0`` (none: the whole lighting on
            the SH path) or ``K`` in ``1..4``; ``None``: ``"auto"`` for this class's own shading path, ``0`` for a
            subclass that shades or computes its own way (it keeps the whole lighting).
        peak_kind: the peaks' visibility, one of :data:`~prt_torch.player.peaks.PEAK_KINDS`; ``None``: ``learned``
            when the run has ``peak_blockers.npz``, else ``spheres`` when it has ``blockers.npz``, else none (the
            peaks cast no shadow; a warning).
    """

    #: whether this player shades the character's own material (``material``, the default BRDF of a character
    #: that has one); a renderer of catalogue BRDFs only sets ``False`` and defaults to the catalogue's first
    shades_material: bool = True

    def __init__(self, run_dir: str | os.PathLike[str] | RunDir, env: str | os.PathLike[str] | None = None,
                 brdf: str | None = None, graph: str | None = None, threads: int = 2,
                 window_size: tuple[int, int] = (480, 640), exposure: ToneMap | None = None, n_lobes: int = 3,
                 blas_threads: int | None = 1, spinning: bool = False, device: str = "cpu",
                 crowd_chunk: int | None = None, peaks: int | str | None = None, peak_kind: str | None = None) -> None:
        check(peak_kind is None or peak_kind in PEAK_KINDS,
              f"unknown peak visibility {peak_kind!r}: expected one of {', '.join(PEAK_KINDS)}")
        check(crowd_chunk is None or int(crowd_chunk) >= 1, f"crowd_chunk must be >= 1, got {crowd_chunk}")
        self.crowd_chunk = None if crowd_chunk is None else int(crowd_chunk)
        check(graph is None or graph in GRAPH_MODES, f"unknown graph mode {graph!r}: expected one of {GRAPH_MODES}")
        self._blas_limit: Any = None
        if blas_threads is not None:
            from threadpoolctl import threadpool_limits

            self._blas_limit = threadpool_limits(limits=int(blas_threads), user_api="blas")
        self.bundle = RunBundle(run_dir, threads=threads, spinning=spinning, device=device,
                                graphs=("visibility", "shading", "fused") + (("fused_peaks",) if graph == "fused_peaks"
                                                                             else ()))
        self.device = device
        #: the fused graph's vertex order (``None``: original); the posing runs in it
        self.vertex_order = self.bundle.vertex_order
        graph = default_graph(self.bundle, device) if graph is None else graph
        self.graph = graph
        #: the compiled frame path (graph ``compiled``; ``None`` otherwise)
        self.compiled: Any = None
        if graph == "compiled":
            check(device == "cpu", "graph 'compiled' runs on the CPU: play graph 'fused' on another device")
            from prt_torch.player.compiled import CompiledFrame

            self.compiled = CompiledFrame(self.bundle, threads=threads, spinning=spinning)
        self.character = self.bundle.character
        self.order = self.bundle.order
        self.window_size = window_size
        #: the lighting split into peak lights + residual (no peaks: the whole lighting)
        self.peaks: PeakLighting = load_peak_lighting(env, self.order, self._default_peaks() if peaks is None
                                                      else peaks, n_lobes)
        #: the lighting of the SH path: the residual when there are peak lights
        self.lighting: Lighting = self.peaks.lighting
        self.light_angle = 0.0
        self._lobe_dirs = self.lighting.dirs
        self._peak_dirs = self.peaks.directions  # (P, 3) world, turned by rotate_light
        #: the compiled peak kernels' numba threads over vertices (default ``False``: the calling thread, measured
        #: faster for one character on 2 cores: 0.71 vs 0.73 ms visibility, 0.16 vs 0.47 ms shading; the ``overlap``
        #: mode always runs the peaks' visibility on one thread, next to the model's worker)
        self.peak_threads = False
        self._peak_brdfs: dict[str, Any] = {}
        # brdf None: the character's own material (a glTF character), else the catalogue's first (player.material)
        self.rpo: RPOTensors = select_rpo(self.bundle, brdf, material=self.shades_material)
        #: the peaks' visibility (``None``: no peaks, or no blockers - the peaks then cast no shadow)
        self.peak_source: PeakVisibility | None = self._peak_source(peak_kind) if self.peaks.peaks else None
        if self.peaks.peaks:
            self.peak_brdf()  # a BRDF without an analytic form fails here, not on the first frame
        if graph == "fused_peaks":
            self._check_fused_peaks()
        self.exposure = exposure
        self.unshadowed = hemisphere_visibility(self.order, self.bundle.below_horizon)
        ch = self.character
        # the fused graph's order when it is the path played (the split graphs take the original order)
        poser: type[Poser] = Poser
        if graph == "compiled":
            from prt_torch.player.compiled import CompiledPoser

            poser = CompiledPoser
        self.poser = poser(ch, self.bundle.cluster, self.bundle.cluster_axis, self.bundle.cluster_bone,
                           order=self.vertex_order if graph in CLUSTER_ORDER_MODES else None)
        self.center, self.radius = camera_target(ch.rest_vertices)
        self.camera_azimuth = CAMERA_AZIMUTH
        self.camera_elevation = CAMERA_ELEVATION
        self._renderer: Any = None
        self._pool: Any = None  # worker thread of the "overlap" mode (created on first use)
        self._vis_overlap: OrtGraph | None = None

    def _default_peaks(self) -> int | str:
        """``peaks=None``: ``"auto"`` when this class shades with the player's own path (:meth:`compute`,
        :meth:`shade`: the peak term is added there), ``0`` for a subclass with its own (it keeps the whole
        lighting, the sun included)."""
        cls = type(self)
        return AUTO if cls.compute is Player.compute and cls.shade is Player.shade else 0

    def _check_fused_peaks(self) -> None:
        """``graph="fused_peaks"`` plays the run's learned peak blockers inside the graph: one-line errors when the
        player's peaks are something else."""
        check(bool(self.peaks.peaks), "graph 'fused_peaks' needs peak lights (peaks='auto' or K > 0)")
        check(self.peak_source is not None and self.peak_source.kind == "learned",
              "graph 'fused_peaks' plays the run's learned peak blockers: peak visibility must be 'learned'")
        check(brdf_code(self.peak_brdf()) is not None,
              f"graph 'fused_peaks' needs an analytic BRDF it knows for RPO {self.rpo.name!r}: play graph 'fused'")

    def _peak_source(self, kind: str | None) -> PeakVisibility | None:
        """The :class:`~prt_torch.player.peaks.PeakVisibility` of ``kind`` (``None``: the run's best, see the class
        doc), or ``None`` with a warning when the run has no blockers at all."""
        run = self.bundle.run
        if kind is None:
            if learned_blockers_path(run) is not None:
                kind = "learned"
            elif run.blockers_path.is_file():
                kind = "spheres"
            else:
                warn(f"{run.path}: no peak blockers ({run.peak_blockers_path.name}, {run.blockers_path.name}): the "
                     f"peak light(s) cast no shadow (--peak-visibility exact traces the mesh)")
                return None
        offset = None
        if kind == "exact":
            from prt_torch.bake.embree import ray_offset

            attrs = run.dataset().attrs if run.dataset_path.is_dir() else {}
            bake = dict(attrs.get("bake") or {})
            offset = float(bake["ray_offset_world"]) if "ray_offset_world" in bake else \
                ray_offset(self.character.rest_vertices, float(bake.get("ray_offset", 1e-4)))
        return peak_visibility(kind, run, self.character, offset=offset)

    def peak_brdf(self, rpo: RPOTensors | None = None) -> Any:
        """The analytic BRDF the RPO ``rpo`` (default the current one) was built from, which shades the peak lights:
        :func:`prt_torch.brdf.rpo.builtin_brdf` for a catalogue name, :func:`prt_torch.rig.material.material_brdf`
        of the character's material for ``material``; another RPO (a file of another BRDF) is a one-line error."""
        name = (self.rpo if rpo is None else rpo).name
        if name not in self._peak_brdfs:
            from prt_torch.brdf.rpo import CATALOGUE
            from prt_torch.rig.material import MATERIAL_BRDF, analytic_brdf, character_material

            brdf = analytic_brdf(name, character_material(self.character))
            if brdf is None:
                raise PrtError(f"the peak lights need the analytic BRDF of RPO {name!r} (one of {', '.join(CATALOGUE)} "
                               f"or {MATERIAL_BRDF!r}): play it with --peaks 0")
            self._peak_brdfs[name] = brdf
        return self._peak_brdfs[name]

    # -- settings ------------------------------------------------------------------------------
    @property
    def eye(self) -> np.ndarray:
        """Camera position (world): :func:`camera_eye` at the current azimuth and elevation."""
        return camera_eye(self.center, self.radius, self.camera_azimuth, self.camera_elevation)

    def set_brdf(self, name: str) -> None:
        """Swap the material (an RPO of the run's catalogue, ``material``: the character's own, or an RPO file)."""
        rpo = select_rpo(self.bundle, name)
        if self.peaks.peaks:
            self.peak_brdf(rpo)  # checked before the swap
        self.rpo = rpo

    def next_brdf(self) -> str:
        names = brdf_names(self.bundle)
        i = (names.index(self.rpo.name) + 1) % len(names) if self.rpo.name in names else 0
        self.set_brdf(names[i])
        return names[i]

    def rotate_light(self, angle: float) -> None:
        """Rotate the lighting about the world up axis by ``angle`` radians (cumulative)."""
        self.light_angle += angle
        c, s = np.cos(self.light_angle), np.sin(self.light_angle)
        R = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]], dtype=np.float32)
        self._lobe_dirs = np.ascontiguousarray(self.lighting.dirs @ R.T)
        self._peak_dirs = self.peaks.rotated_about_z(self.light_angle).directions if self.peaks.peaks \
            else self.peaks.directions

    def orbit(self, d_azimuth: float, d_elevation: float = 0.0) -> None:
        self.camera_azimuth += d_azimuth
        self.camera_elevation = float(np.clip(self.camera_elevation + d_elevation, -1.2, 1.2))

    # -- per-frame path ------------------------------------------------------------------------
    def clip_locals(self, clip: str | Clip, fps: float | None = None) -> np.ndarray:
        """``(F, J, 4, 4)`` local joint transforms of a clip of the character."""
        c = self.character.clip(clip)
        if fps is not None and fps != c.fps:
            c = c.resample(fps)
        return np.asarray(c.local)

    def crowd_locals(self, clips: list[str | Clip] | tuple[str | Clip, ...], frame: int,
                     stagger: int = 0) -> np.ndarray:
        """``(N, J, 4, 4)`` locals of a crowd of ``N = len(clips)`` characters at ``frame``: character ``i`` plays
        ``clips[i]`` (looping) ``i * stagger`` frames ahead - one batch for :meth:`compute`."""
        check(len(clips) > 0, "a crowd needs at least one clip")
        out = []
        for i, c in enumerate(clips):
            loc = self._clip_cache(c)
            out.append(loc[(frame + i * stagger) % len(loc)])
        return np.stack(out)

    def _clip_cache(self, clip: str | Clip) -> np.ndarray:
        key = clip if isinstance(clip, str) else id(clip)
        cache = self.__dict__.setdefault("_clips", {})
        if key not in cache:
            cache[key] = self.clip_locals(clip)
        return cache[key]

    def pose(self, local: np.ndarray) -> PoseBatch:
        """numpy FK, LBS, local frames, pose features and view directions for ``(B, J, 4, 4)`` locals."""
        return self.poser(local, self.eye)

    def _light_feeds(self, rpo: RPOTensors | None = None) -> dict[str, np.ndarray]:
        """The lighting and RPO inputs every shading graph takes (``rpo``: default the player's current one)."""
        rpo = self.rpo if rpo is None else rpo
        return {"lobe_dirs": self._lobe_dirs, "lobe_coeffs": self.lighting.coeffs, "rpo_M": rpo.M, "rpo_w": rpo.w,
                "rpo_tint": rpo.tint}

    def _fused_feeds(self, state: PoseBatch) -> dict[str, np.ndarray]:
        """The fused graph's inputs: frames and view directions in its vertex order (free when posed in it)."""
        o = self.vertex_order
        return {"pose": state.features, "frames": state.in_order("frames", o),
                "view_dirs": state.in_order("view_dirs", o), **self._light_feeds()}

    def _to_original(self, radiance: np.ndarray) -> np.ndarray:
        """``(B, V, 3)`` radiance from the fused graph's vertex order back to the original one."""
        if self.vertex_order is None:
            return radiance
        out = np.empty_like(radiance)
        out[:, self.vertex_order] = radiance
        return out

    def _shading_feeds(self, state: PoseBatch, rpo: RPOTensors | None = None) -> dict[str, np.ndarray]:
        return {"frames": state.frames, "view_dirs": state.view_dirs, **self._light_feeds(rpo)}

    def visibility(self, features: np.ndarray, checked: bool = True) -> np.ndarray:
        """``(B, A)`` pose features -> ``(B, V, C)`` local visibility (ORT)."""
        g = self.bundle.graphs["visibility"]
        if checked:
            return g.run({"pose": features})["visibility"]
        return g.run_unchecked({"pose": features})[0]

    def shade(self, state: PoseBatch, visibility: np.ndarray | None = None, checked: bool = True,
              timer: FrameTimer | None = None, rpo: RPOTensors | None = None) -> np.ndarray:
        """Radiance ``(B, V, 3)``: from the model (``visibility=None``) or a given ``(B, V, C)`` visibility.
        ``rpo``: shade with this RPO instead of the player's current BRDF (needs ``visibility``)."""
        check(rpo is None or visibility is not None, "Player.shade: rpo= needs the visibility")
        if visibility is None and self.graph == "compiled":  # one compiled pass for all B characters
            t0 = time.perf_counter()
            o = self.vertex_order
            out = self.compiled.radiance(state.features, state.in_order("frames", o), state.in_order("view_dirs", o),
                                         self._lobe_dirs, self.lighting.coeffs, self.rpo)
            if timer is not None:
                timer.add("compiled", time.perf_counter() - t0)
            return out
        if visibility is None and self.graph == "fused":  # one call for all B characters
            g = self.bundle.graphs["fused"]
            t0 = time.perf_counter()
            feeds = self._fused_feeds(state)
            n_b, step = state.features.shape[0], self.crowd_chunk or state.features.shape[0]
            if n_b <= step:
                out = g.run(feeds)["radiance"] if checked else g.run_unchecked(feeds)[0]
            else:
                parts = []
                for s in range(0, n_b, step):
                    f = {k: (v[s:s + step] if k in ("pose", "frames", "view_dirs") else v) for k, v in feeds.items()}
                    parts.append(g.run(f)["radiance"] if checked else g.run_unchecked(f)[0])
                out = np.concatenate(parts)
            out = self._to_original(out)
            if timer is not None:
                timer.add("fused", time.perf_counter() - t0)
            return out
        feeds = self._shading_feeds(state, rpo)
        if visibility is None and state.features.shape[0] > 1:
            return self._shade_batch(state, feeds, checked, timer)
        t0 = time.perf_counter()
        if visibility is None:
            visibility = self.visibility(state.features, checked)
        t1 = time.perf_counter()
        g = self.bundle.graphs["shading"]
        feeds["visibility"] = np.ascontiguousarray(np.broadcast_to(
            visibility, (state.frames.shape[0], state.frames.shape[2], self.order ** 2)), dtype=np.float32)
        out = g.run(feeds)["radiance"] if checked else g.run_unchecked(feeds)[0]
        if timer is not None:
            timer.add("visibility", t1 - t0)
            timer.add("shading", time.perf_counter() - t1)
        return out

    def _shade_batch(self, state: PoseBatch, feeds: dict[str, np.ndarray], checked: bool,
                     timer: FrameTimer | None) -> np.ndarray:
        """``B > 1`` characters, split graphs: ONE visibility call for the batch (the model's weights stream once
        for all ``B`` poses: per-cluster GEMMs instead of GEMVs), then ONE shading call."""
        t0 = time.perf_counter()
        vis = self.visibility(state.features, checked)  # (B, V, C)
        t1 = time.perf_counter()
        g = self.bundle.graphs["shading"]
        feeds["visibility"] = vis
        out = g.run(feeds)["radiance"] if checked else g.run_unchecked(feeds)[0]
        if timer is not None:
            timer.add("visibility", t1 - t0)
            timer.add("shading", time.perf_counter() - t1)
        return out

    def _shade_each(self, state: PoseBatch, vis: np.ndarray, feeds: dict[str, np.ndarray],
                    checked: bool) -> np.ndarray:
        """Radiance ``(B, V, 3)`` from visibility ``(B, V, C)``, one shading call per character."""
        g = self.bundle.graphs["shading"]
        n_b = vis.shape[0]
        out = np.empty((n_b, self.bundle.n_vertices, 3), np.float32)
        for i in range(n_b):
            feeds["visibility"] = vis[i:i + 1]
            feeds["frames"] = state.frames[i:i + 1]
            feeds["view_dirs"] = state.view_dirs[i:i + 1]
            out[i] = (g.run(feeds)["radiance"] if checked else g.run_unchecked(feeds)[0])[0]
        return out

    def compute(self, local: np.ndarray, timer: FrameTimer | None = None) -> tuple[PoseBatch, np.ndarray]:
        """The whole per-frame compute path for ``(B, J, 4, 4)`` locals -> (posed batch, radiance (B, V, 3)): the
        graph(s) of :attr:`graph` with the residual lighting, plus the peak lights' term (the batch's
        ``peak_visibility`` and ``residual_radiance`` are set)."""
        if self.graph == "overlap":
            return self.compute_overlapped(local, timer)
        t0 = time.perf_counter()
        state = self.pose(local)
        if timer is not None:
            timer.add("pose", time.perf_counter() - t0)
        if self.graph == "fused_peaks":
            return state, self._fused_peaks(state, timer)
        return state, self._with_peaks(state, self.shade(state, checked=False, timer=timer), timer)

    def _fused_peaks(self, state: PoseBatch, timer: FrameTimer | None) -> np.ndarray:
        """``graph="fused_peaks"``: the whole radiance ``(B, V, 3)`` from one graph call (original order); sets the
        batch's ``peak_visibility`` (its ``residual_radiance`` stays ``None``: the graph returns the sum)."""
        t0 = time.perf_counter()
        o = self.vertex_order
        brdf = self.peak_brdf()
        code = brdf_code(brdf)
        assert code is not None and state.skin is not None
        feeds = {**self._fused_feeds(state), "positions": state.in_order("positions", o),
                 "skin": state.skin.astype(np.float32), "peak_directions": self._peak_dirs.astype(np.float32),
                 "peak_radii": np.asarray(self.peaks.angular_radii, np.float32),
                 "peak_powers": (np.asarray(self.peaks.powers) * np.asarray(brdf.tint)[None]).astype(np.float32),
                 "peak_brdf": np.r_[code[0], code[1]].astype(np.float32)}
        radiance, vis = self.bundle.graphs["fused_peaks"].run_unchecked(feeds)
        state.residual_radiance = None
        state.peak_visibility = self._to_original(vis)
        if timer is not None:
            timer.add("fused", time.perf_counter() - t0)
        return self._to_original(radiance)

    def compute_overlapped(self, local: np.ndarray,
                           timer: FrameTimer | None = None) -> tuple[PoseBatch, np.ndarray]:
        """:meth:`compute` with the visibility model running WHILE numpy poses the mesh (graph ``"overlap"``).

        The model needs only the pose features (``Poser.features``, ~40 us), so its onnxruntime call (which
        releases the GIL) runs on a worker thread - with ONE intra-op thread, its own session - while the
        main thread does FK, LBS, frames and view directions on the other core, then the peaks' visibility (it
        needs the posed mesh, not the model); then the split shading graph and the peaks' term. Same numbers as
        the split path.
        """
        t0 = time.perf_counter()
        feats = self.poser.features(local)
        if self._pool is None:
            from concurrent.futures import ThreadPoolExecutor

            self._pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="prt-visibility")
            self._vis_overlap = OrtGraph(self.bundle.graphs["visibility"].path, threads=1)
        fut = self._pool.submit(self._vis_overlap.run_unchecked, {"pose": feats})
        state = self.poser(local, self.eye, features=feats)
        t1 = time.perf_counter()
        peak_vis = self._peak_visibility_raw(state, False) if self.peaks.peaks else None  # while the model runs
        t2 = time.perf_counter()
        vis = fut.result()[0]
        t3 = time.perf_counter()
        out = self._shade_each(state, vis, self._shading_feeds(state), checked=False)
        t4 = time.perf_counter()
        out = self._with_peaks(state, out, None, peak_vis)
        if timer is not None:
            timer.add("pose", t1 - t0)
            timer.add("visibility", t3 - t2)  # the part of the model call not hidden behind the posing and peaks
            timer.add("shading", t4 - t3)
            timer.add("peaks", (t2 - t1) + (time.perf_counter() - t4))
        return state, out

    # -- peak lights -----------------------------------------------------------------------------
    def _peak_visibility_raw(self, state: PoseBatch, threads: bool | None = None) -> np.ndarray:
        """``(B, V, P)`` peak visibility in the batch's own (posed) vertex order (a per-vertex kind: no permutation;
        ``exact`` traces the mesh in the original order, then is put in the posed one)."""
        dirs, radii = self._peak_dirs, self.peaks.angular_radii
        src = self.peak_source
        threads = self.peak_threads if threads is None else threads
        if src is None:  # no blockers: the discs' share above each horizon only (no shadow)
            b = state.features.shape[0]
            return sphere_visibility_soa(state.in_order("positions", state.order), state.in_order("normals",
                                         state.order), np.zeros((b, 0, 3), np.float32), np.zeros(0, np.float32),
                                         dirs, radii, threads=threads)
        if src.per_vertex:  # in a compact order (the posed one, else the export's cluster-sorted one): the kernel
            o = state.order if state.order is not None else self.vertex_order  # culls spheres per vertex block
            vis = src.vertex_last(state.in_order("positions", o), state.in_order("normals", o), state.skin, dirs, radii,
                                  threads=threads)
            if o is state.order:
                return vis
            back = np.empty_like(vis)
            back[:, o] = vis
            return back
        vis = src.vertex_last(state.positions, state.normals, state.skin, dirs, radii, threads=threads)
        return vis if state.order is None else np.ascontiguousarray(vis[:, state.order])

    def peak_visibility(self, state: PoseBatch) -> np.ndarray:
        """``(B, V, P)`` float32 visible fraction of each peak's disc per vertex of a posed batch (original vertex
        order; :attr:`peak_source`, turned with the light)."""
        return self._to_original_of(state, self._peak_visibility_raw(state))

    @staticmethod
    def _to_original_of(state: PoseBatch, x: np.ndarray) -> np.ndarray:
        """``(B, V, ...)`` from the batch's posed vertex order back to the original one."""
        if state.order is None:
            return x
        out = np.empty_like(x)
        out[:, state.order] = x
        return out

    def shade_peaks(self, state: PoseBatch, visibility: np.ndarray) -> np.ndarray:
        """``(B, V, 3)`` float32 radiance of the peak lights, ``sum_p E_p f_r(l_p, v) max(n . l_p, 0) V_p``, for a
        posed batch and its ``visibility (B, V, P)`` (original vertex order; :meth:`peak_brdf`, the directions
        turned with the light, ``v`` toward the eye of the batch's view directions)."""
        return peak_radiance_soa(state.frames, state.view_dirs, self._peak_dirs, self.peaks.powers, visibility,
                                self.peak_brdf(), threads=self.peak_threads)

    def _with_peaks(self, state: PoseBatch, residual: np.ndarray, timer: FrameTimer | None,
                    raw_visibility: np.ndarray | None = None) -> np.ndarray:
        """``residual (B, V, 3)`` (the SH path's radiance, original order) plus the peaks' term; sets the batch's
        ``residual_radiance`` and ``peak_visibility`` (original order). ``raw_visibility``: the peaks' visibility
        already computed in the batch's posed order."""
        state.residual_radiance = residual
        if not self.peaks.peaks:
            state.peak_visibility = np.zeros((*residual.shape[:2], 0), np.float32)
            return residual
        t0 = time.perf_counter()
        vis = self._peak_visibility_raw(state) if raw_visibility is None else raw_visibility
        o = state.order
        term = peak_radiance_soa(state.in_order("frames", o), state.in_order("view_dirs", o), self._peak_dirs,
                                self.peaks.powers, vis, self.peak_brdf(), threads=self.peak_threads)  # posed order
        state.peak_visibility = self._to_original_of(state, vis)
        out = residual + self._to_original_of(state, term)
        if timer is not None:
            timer.add("peaks", time.perf_counter() - t0)
        return out

    def surface_radiance(self, radiance: np.ndarray) -> np.ndarray:
        """The character's ``radiance (V, 3)`` times its base colour (its material,
        :mod:`prt_torch.player.material`; per vertex), what :meth:`colors` tone-maps."""
        return self.albedo.apply(radiance)

    @property
    def albedo(self) -> SurfaceAlbedo:
        """The character's base colour, the one rule (:func:`prt_torch.player.material.surface_albedo`): per vertex
        in :meth:`colors`, per pixel in a textured character's rendered images."""
        albedo = getattr(self, "_albedo", None)
        if albedo is None:
            albedo = self._albedo = surface_albedo(self.character)
        return albedo

    def tone(self, radiance: np.ndarray) -> np.ndarray:
        """uint8 colours of any ``radiance (N, 3)`` (the character's surface radiance, or a floor's) under the
        player's tone map; fixes it (exposure, white) from the first call when it was not given."""
        if self.exposure is None:
            self.exposure = auto_tonemap(radiance)
        return self.exposure(radiance)

    def colors(self, radiance: np.ndarray) -> np.ndarray:
        """uint8 colours of the character's ``radiance (V, 3)``: :meth:`surface_radiance` (the base colour
        multiplies it per vertex here; a textured character's rendered images multiply it per pixel:
        :meth:`render_frame`) through :meth:`tone`."""
        return self.tone(self.surface_radiance(radiance))

    # -- rendering -----------------------------------------------------------------------------
    def renderer(self, off_screen: bool = True):  # -> MeshRenderer
        from prt_torch.player.render import MeshRenderer

        if self._renderer is None or self._renderer.off_screen != off_screen:
            if self._renderer is not None:
                self._renderer.close()
            alb = self.albedo  # a textured character: base colour per pixel
            self._renderer = MeshRenderer(self.character.rest_vertices, self.character.faces,
                                          window_size=(self.window_size[1], self.window_size[0]),
                                          off_screen=off_screen, uv=alb.uv, texture=alb.texture)
        self._renderer.set_camera(self.eye, self.center)
        return self._renderer

    def render_frame(self, state: PoseBatch, radiance: np.ndarray, index: int = 0) -> np.ndarray:
        """Render character ``index`` with ``radiance (B, V, 3)`` to an ``(H, W, 3)`` uint8 image (offscreen)."""
        r = self.renderer(off_screen=True)
        col = self.colors(radiance[index])  # fixes the tone map on the first call
        r.update(state.positions_vx3(index), col, radiance=radiance[index], tonemap=self.exposure)
        return r.render()

    def follow(self, clip: Any, fps: float | None = None) -> Any:
        """The follow camera (:func:`prt_torch.player.follow.clip_follow`) of ``clip`` (a name or a
        :class:`~prt_torch.rig.clip.Clip` of the character) at ``fps`` (default the clip's rate), as :meth:`play`
        frames it; ``None`` for frames that are not a clip of the character's joints (a cloth sequence keeps its own
        camera, :func:`sequence_view`)."""
        if not isinstance(clip, str | Clip):
            return None
        from prt_torch.player.follow import clip_follow

        return clip_follow(self.character, clip, fps)

    def _aim(self, frame: int) -> None:
        """Point the camera at ``frame`` of the clip being played (the follow track's centre and radius; nothing
        with the fixed camera)."""
        track = getattr(self, "_track", None)
        if track is not None:
            self.center, self.radius = track.at(frame)

    def play(self, clip: str | Clip, out: str | os.PathLike[str] | None = None,
             png_dir: str | os.PathLike[str] | None = None, max_frames: int | None = None,
             fps: float | None = None, timings: str | os.PathLike[str] | None = None,
             show: bool = False, progress: bool = True, camera: str = "follow",
             viewer: dict[str, Any] | None = None) -> PlayResult:
        """Play ``clip``: offscreen into an MP4 (``out``) and/or PNG frames (``png_dir``), or in a window.

        Args:
            clip: clip name of the character, or a :class:`~prt_torch.rig.clip.Clip` of its joints.
            out: MP4 path (written atomically), or ``None``.
            png_dir: directory for ``frame_00000.png`` ..., or ``None``.
            max_frames: play at most this many frames.
            fps: resample the clip (and the video) to this rate.
            timings: JSON file for per-frame step timings.
            show: an interactive window (needs a display; :class:`prt_torch.player.viewer.Viewer`): the clip at its
                rate, looping until closed; keys ``space`` pause, ``period`` / ``comma`` step, ``l`` rotate light,
                ``b`` next BRDF, ``Left``/``Right``/``Up``/``Down`` orbit the camera, ``h`` the key list, ``q`` quit.
            camera: ``"follow"`` (the default: :mod:`prt_torch.player.follow`, the posed character framed over a
                window of frames, smoothly) or ``"fixed"`` (the rest pose's box). The player's :attr:`center` and
                :attr:`radius` are the frame's while it plays and what they were afterwards.
            viewer: keyword options of the window's :class:`~prt_torch.player.viewer.Viewer` (``clock``,
                ``sleep``, ``on_tick``).
        """
        from prt_torch.player.render import has_display

        check(camera in CAMERA_MODES, f"unknown camera {camera!r}: expected one of {', '.join(CAMERA_MODES)}")
        locals_ = self.clip_locals(clip, fps)
        rate = float(fps or self.character.clip(clip).fps)  # a Clip (e.g. a split's frame range) passes through
        track = self.follow(clip, fps) if camera == "follow" else None
        clip = clip if isinstance(clip, str) else clip.name
        n = len(locals_) if max_frames is None else max(0, min(int(max_frames), len(locals_)))
        check(n > 0, f"clip {clip!r}: nothing to play (max_frames={max_frames})")
        if show and not has_display():
            raise PrtError("no display for an interactive window: pass --out video.mp4 or --png DIR instead")
        timer = FrameTimer()
        outputs: list[Path] = []
        saved = (self.center, self.radius)
        self._track = track
        try:
            if show:
                n = self._view(locals_, n, rate, clip, timer, viewer or {})
            else:
                self._play_offscreen(locals_, n, rate, clip, timer, out, png_dir, progress, outputs)
        finally:
            self._track = None
            self.center, self.radius = saved
        summary = timer.summary()
        if timings is not None:
            timer.write_json(timings, extra={"clip": clip, "graph": self.graph, "brdf": self.rpo.name,
                                             "lighting": self.lighting.source, **self.peaks.to_dict(),
                                             "peak_visibility": None if self.peak_source is None
                                             else self.peak_source.kind, "n_vertices": self.bundle.n_vertices,
                                             "sh_order": self.order, "exposure": self.exposure.exposure,
                                             "white": self.exposure.white, "camera": camera})
            outputs.append(Path(timings))
        return PlayResult(n, summary, outputs)

    def _play_offscreen(self, locals_: Any, n: int, rate: float, clip: str, timer: FrameTimer,
                        out: str | os.PathLike[str] | None, png_dir: str | os.PathLike[str] | None, progress: bool,
                        outputs: list[Path]) -> None:
        """:meth:`play` into an MP4 and/or PNG frames (or compute only); appends the written paths to ``outputs``."""
        from prt_torch.player.video import VideoWriter, write_png

        writer = VideoWriter(out, fps=rate) if out is not None else None
        if png_dir is not None:
            Path(png_dir).mkdir(parents=True, exist_ok=True)
        renderer = self.renderer(off_screen=True) if writer is not None or png_dir is not None else None
        prog = _progress(progress, n, f"playing {clip}")
        try:
            for i, (state, radiance) in enumerate(self.compute_stream(locals_, n, timer)):
                with timer.step("colors"):
                    col = self.colors(radiance[0])
                if renderer is not None:
                    with timer.step("render"):
                        renderer.set_camera(self.eye, self.center)
                        renderer.update(state.positions_vx3(0), col, radiance=radiance[0], tonemap=self.exposure)
                        img = renderer.render()
                    with timer.step("write"):
                        if writer is not None:
                            writer.append(img)
                        if png_dir is not None:
                            write_png(Path(png_dir) / f"frame_{i:05d}.png", img)
                if prog is not None:
                    prog.advance()
        except BaseException:
            if writer is not None:
                writer.abort()
            raise
        finally:
            if prog is not None:
                prog.stop()
        if writer is not None:
            outputs.append(writer.close())
        if png_dir is not None:
            outputs.append(Path(png_dir))

    def _view(self, locals_: Any, n: int, rate: float, clip: str, timer: FrameTimer, options: dict[str, Any]) -> int:
        """:meth:`play` in a window (:class:`~prt_torch.player.viewer.Viewer`); returns the frames drawn."""
        from prt_torch.player.viewer import Viewer

        renderer = self.renderer(off_screen=False)

        def draw(i: int) -> None:
            self._aim(i)
            state, radiance = self.compute(locals_[i:i + 1], timer)
            with timer.step("colors"):
                col = self.colors(radiance[0])
            with timer.step("render"):
                renderer.set_camera(self.eye, self.center)
                renderer.update(state.positions_vx3(0), col, radiance=radiance[0], tonemap=self.exposure)

        step, tilt = np.radians(10), np.radians(8)
        actions = {"Left": lambda: self.orbit(-step), "Right": lambda: self.orbit(step),
                   "Up": lambda: self.orbit(0, tilt), "Down": lambda: self.orbit(0, -tilt),
                   "l": lambda: self.rotate_light(np.radians(15)), "b": self.next_brdf}
        try:
            return Viewer(renderer, n, rate, draw, actions, title=f"prt play {clip}", **options).run()
        finally:
            self._renderer = None  # the viewer closed its window

    def compute_stream(self, locals_: Any, n: int, timer: FrameTimer | None = None) -> Iterator[tuple[PoseBatch,
                                                                                                     np.ndarray]]:
        """``(state, radiance)`` of frames ``0 .. n-1`` of ``locals_`` in order (what :meth:`play` renders): one
        :meth:`compute` per frame here, the camera aimed at each frame first (:meth:`_aim`); a subclass may keep
        several frames in flight."""
        for i in range(n):
            self._aim(i)
            yield self.compute(locals_[i:i + 1], timer)

    def close(self) -> None:
        if self._pool is not None:
            self._pool.shutdown(wait=True)
            self._pool = None
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None
        if self._blas_limit is not None:
            self._blas_limit.restore_original_limits()
            self._blas_limit = None


class _progress:
    """A small rich progress bar with a live frames/s readout (or nothing when disabled)."""

    def __new__(cls, enabled: bool, total: int, label: str):  # type: ignore[misc]
        if not enabled:
            return None
        return super().__new__(cls)

    def __init__(self, enabled: bool, total: int, label: str) -> None:
        from prt_torch.progress import progress_bar

        self._p = progress_bar(fields=("{task.fields[fps]:.1f} frames/s",), transient=False)
        self._t = self._p.add_task(label, total=total, fps=0.0)
        self._t0 = time.perf_counter()
        self._n = 0
        self._p.start()

    def advance(self) -> None:
        self._n += 1
        self._p.update(self._t, advance=1, fps=self._n / max(time.perf_counter() - self._t0, 1e-9))

    def stop(self) -> None:
        self._p.stop()
